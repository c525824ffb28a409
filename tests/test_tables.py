"""gspi-table on plain gspi-eval folders: Table 1 layout, best/second marks, '--' for missing
channels, runs of one method averaged, protocol/data/scene mixing refused. The same builder
and renderer as sweeps (tests/test_tables_sweep.py)."""
import json

import pytest
from omegaconf import OmegaConf

from eval.records.eval_folder import find_eval_folders
from eval.tables.sources import load_eval_folders
from eval.tables.cli import positional_to_overrides, run
from eval.tables.render import to_latex, to_markdown
from eval.tables.build import TABLE_SPECS, build_sweep_table


def build(root):
    sweep = load_eval_folders([root])
    return build_sweep_table(sweep, TABLE_SPECS["table1"]), sweep


def _write_run(root, name, summary, method, protocol=("gspi-decoupled", 1), runtime=(1.5, 3.0),
               **meta):
    d = root / name
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps(summary))
    (d / "eval_meta.json").write_text(json.dumps({
        "method": method, "protocol": {"name": protocol[0], "version": protocol[1]},
        "runtime_min": {"material": runtime[0], "end_to_end": runtime[1]}, **meta}))
    return d


def _summary(psnr, ssim, lpips, channels=("albedo", "roughness", "metallic", "relight")):
    return {c: {"psnr": psnr, "ssim": ssim, "lpips": lpips} for c in channels}


@pytest.fixture
def runs(tmp_path):
    _write_run(tmp_path, "a", _summary(20.0, 0.8, 0.05), "A", runtime=(5.4, 10.4))
    _write_run(tmp_path, "b", _summary(25.0, 0.9, 0.02), "B", runtime=(30.0, 35.0))
    _write_run(tmp_path, "c", _summary(15.0, 0.5, 0.09, channels=("albedo", "relight")), "C",
               runtime=(2.0, 8.0))
    return tmp_path


def test_best_and_second_per_column(runs):
    table, _ = build(runs)
    marks = table.marks
    assert marks.loc["B", "psnr/albedo"] == 1 and marks.loc["A", "psnr/albedo"] == 2
    assert marks.loc["B", "lpips/albedo"] == 1 and marks.loc["C", "lpips/albedo"] == 0
    assert marks.loc["C", "minutes/material"] == 1 and marks.loc["A", "minutes/material"] == 2
    assert marks.loc["A", "psnr/roughness"] == 2  # C has no roughness: not ranked


def test_percent_units_and_missing_channel(runs):
    table, sweep = build(runs)
    assert table.mean.loc["B", "ssim/albedo"] == pytest.approx(90.0)
    assert table.mean.loc["A", "lpips/relight"] == pytest.approx(5.0)
    md = to_markdown(table, sweep)
    c_row = next(line for line in md.splitlines() if line.startswith("| C |"))
    # roughness and metallic in three metric groups, and Δ (no GS-PI row to compare with)
    assert c_row.count("--") == 7
    assert "**25.00**" in md and "<u>20.00</u>" in md and "<u>5.4</u> (10.4)" in md
    tex = to_latex(table, sweep)
    assert r"\cellcolor{BaselineBestCell}\textbf{25.00}" in tex and r"\toprule" in tex


def test_runs_of_one_method_are_averaged(tmp_path):
    _write_run(tmp_path, "s0", _summary(20.0, 0.8, 0.05), "A")
    _write_run(tmp_path, "s1", _summary(22.0, 0.6, 0.07), "A")
    table, _ = build(tmp_path)
    assert table.labels == ["A"] and table.mean.loc["A", "psnr/metallic"] == pytest.approx(21.0)
    assert table.count.loc["A", "psnr/metallic"] == 2  # two (scene, run) units


def test_mixed_protocols_are_refused(tmp_path):
    _write_run(tmp_path, "a", _summary(20.0, 0.8, 0.05), "A")
    _write_run(tmp_path, "b", _summary(20.0, 0.8, 0.05), "B", protocol=("gspi-decoupled", 2))
    with pytest.raises(ValueError, match="different protocols"):
        build(tmp_path)


def test_run_writes_three_formats(runs, tmp_path):
    cfg = OmegaConf.create({"runs": [str(runs)], "out": str(tmp_path / "tables")})
    run(cfg)
    import pandas as pd

    md, tex = ((tmp_path / "tables" / f"table1.{s}").read_text() for s in ("md", "tex"))
    csv = pd.read_csv(tmp_path / "tables" / "table1.csv")
    assert list(csv["label"]) == ["A", "B", "C"]
    assert any(c.startswith("psnr/albedo") for c in csv.columns)
    assert md.count("\n|") >= 2 and "\\begin{tabular}" in tex
    for label in csv["label"]:  # every row of the csv is in the md and tex tables
        assert f"| {label} |" in md and f"{label} &" in tex


def test_positional_dirs_become_runs_override():
    assert positional_to_overrides(["a/b", "out=x", "c"]) == ["out=x", "runs=[a/b,c]"]
    assert positional_to_overrides(["out=x"]) == ["out=x"]


def test_missing_folder_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no complete gspi-eval folder"):
        find_eval_folders([tmp_path])


def test_positional_folders_may_contain_equals_signs(tmp_path):
    """Hydra names sweep job folders `method=gspi`: an existing path is a folder, not an override."""
    from eval.tables.cli import positional_to_overrides

    job = tmp_path / "method=gspi"
    job.mkdir()
    args = positional_to_overrides([str(job), "out=x"])
    assert args == ["out=x", f"runs=['{job}']"]
    assert positional_to_overrides(["a", "b", "out=x"]) == ["out=x", "runs=[a,b]"]


def test_one_killed_gspi_eval_folder_is_named_and_skipped(runs, tmp_path):
    killed = runs / "killed"
    (killed / ".hydra").mkdir(parents=True)          # killed before summary.json
    half = runs / "half"
    half.mkdir()
    (half / "summary.json").write_text("{}")          # killed before eval_meta.json
    table = run(OmegaConf.create({"runs": [str(runs)], "out": str(tmp_path / "t")}))["table1"]
    assert sorted(table.labels) == ["A", "B", "C"]
    md = (tmp_path / "t" / "table1.md").read_text()
    assert "Incomplete gspi-eval folder(s) left out" in md
    assert str(killed) in md and str(half) in md


def test_only_killed_folders_is_an_error_naming_them(tmp_path):
    (tmp_path / "k" / ".hydra").mkdir(parents=True)
    (tmp_path / "h").mkdir()
    (tmp_path / "h" / "summary.json").write_text("{}")
    with pytest.raises(FileNotFoundError, match="incomplete .killed.. folders: .*h"):
        find_eval_folders([tmp_path / "h"])


@pytest.mark.parametrize("key, a, b, message", [
    ("data", "/d/small", "/d/tiny", "method=A ablation=full was scored on different datasets"),
    ("scenes", ["s1", "s2"], ["s1"], "method 'A': its runs were scored on different scene sets")])
def test_runs_of_one_method_on_different_data_are_refused(tmp_path, key, a, b, message):
    _write_run(tmp_path, "r0", _summary(20.0, 0.8, 0.05), "A", **{key: a})
    _write_run(tmp_path, "r1", _summary(22.0, 0.6, 0.07), "A", **{key: b})
    with pytest.raises(ValueError, match=f"{message}(.|\n)*r0(.|\n)*r1"):
        build(tmp_path)


def test_protocol_refusal_names_runs_and_differing_keys(tmp_path):
    base = {"name": "gspi-decoupled", "version": 1, "relight": {"tonemap": "aces"}}
    _write_run(tmp_path, "a", _summary(20.0, 0.8, 0.05), "A", protocol_config=base)
    _write_run(tmp_path, "b", _summary(20.0, 0.8, 0.05), "B",
               protocol_config=dict(base, relight={"tonemap": "clamp"}))
    with pytest.raises(ValueError) as err:
        build(tmp_path)
    assert "relight.tonemap: 'aces' != 'clamp'" in str(err.value)
    assert str(tmp_path / "a") in str(err.value) and str(tmp_path / "b") in str(err.value)


def test_footer_of_a_protocol_recorded_before_the_floor_says_so():
    from eval.protocol_id import describe_protocol

    old = {"name": "gspi-decoupled", "version": 1, "split": "test", "albedo_alignment": "none",
           "lpips": {"net": "alex", "version": "0.1", "mode": "masked_mean"},
           "relight": {"tonemap": "aces", "srgb": True}}
    text = describe_protocol(old)
    assert "no MSE floor (recorded before the floor" in text and "LPIPS alex v0.1" in text
    assert "knobs unknown" in describe_protocol({"name": "p", "version": 1})


def test_resources_add_a_peak_memory_column_and_the_default_table_has_none(runs, tmp_path):
    _write_run(tmp_path / "more", "d", _summary(18.0, 0.7, 0.06), "D", peak_memory_mb={"rss": 812.4})
    from eval.tables.build import with_resources

    sweep = load_eval_folders([runs, tmp_path / "more"])
    plain = to_markdown(build_sweep_table(sweep, TABLE_SPECS["table1"]), sweep)
    table = build_sweep_table(sweep, with_resources(TABLE_SPECS["table1"]))
    md = to_markdown(table, sweep)
    assert "Peak RSS" not in plain and "Peak RSS (MB)" in md.splitlines()[2]
    d_row = next(line for line in md.splitlines() if line.startswith("| D |"))
    a_row = next(line for line in md.splitlines() if line.startswith("| A |"))
    assert "| 812 |" in d_row and "10.4) | -- |" in a_row  # A recorded no peak: "--"
    assert table.marks["mb/peak_rss"].eq(0).all()  # memory is shown, never ranked


def test_resources_give_table2_a_time_and_memory_column():
    from eval.tables.build import with_resources

    cols = [(c.measure, c.channel) for c in with_resources(TABLE_SPECS["table2"]).columns]
    assert cols[-3:] == [("runtime", "material"), ("runtime", "end_to_end"), ("memory", "peak_rss")]


def test_gspi_table_resources_option_writes_the_memory_column(tmp_path):
    _write_run(tmp_path / "runs", "a", _summary(20.0, 0.8, 0.05), "A", peak_memory_mb={"rss": 1024.0})
    for resources, expected in ((False, False), (True, True)):
        out = tmp_path / f"tables_{resources}"
        run(OmegaConf.create({"runs": [str(tmp_path / "runs")], "out": str(out), "resources": resources}))
        assert ("Peak RSS (MB)" in (out / "table1.md").read_text()) is expected
        assert ("mb/peak_rss/mean" in (out / "table1.csv").read_text()) is expected


def test_gspi_table_over_two_protocols_is_one_line_exit_2(tmp_path):
    """The refusal was a good message inside ~15 lines of traceback, exit 1."""
    from eval.tables.cli import main
    from tests.reliability.helpers import run_cli

    base = {"name": "gspi-decoupled", "version": 1, "ssim": {"window": 11}}
    _write_run(tmp_path / "runs", "a", _summary(20.0, 0.8, 0.05), "A", protocol_config=base)
    _write_run(tmp_path / "runs", "b", _summary(20.0, 0.8, 0.05), "B",
               protocol_config=dict(base, ssim={"window": 3}))
    code, text = run_cli(main, [str(tmp_path / "runs" / "a"), str(tmp_path / "runs" / "b"),
                                f"out={tmp_path / 'tables'}"])
    lines = [line for line in text.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, text
    assert "different protocols" in lines[0] and "ssim.window: 11 != 3" in lines[0]
    assert str(tmp_path / "runs" / "b") in lines[0] and "Traceback" not in text
    assert not (tmp_path / "tables" / "table1.md").exists()
