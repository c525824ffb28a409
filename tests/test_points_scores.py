"""gspi-table on Stage II point-cloud evaluations (evaluate_points' scores.json) -> Table 2.

Fake folders with known per-scene numbers; every expected cell is recomputed here with numpy.
"""
import json
from pathlib import Path

import numpy as np
import pytest

from eval.tables.sources import load_points_folders
from eval.stats import paired_bootstrap_ci
from eval.tables.cli import load_sources
from eval.tables.build import TABLE_SPECS, build_sweep_table

SCENES = ("p0224_a", "p0225_b", "p0226_c", "p0227_d")
CHANNELS = ("albedo", "roughness", "metallic")
OFFSETS = {"full": 0.0, "a1_no_global_prior": -2.0, "a3_npts_1024": -0.5}


def psnr(ablation: str, scene: str, channel: str) -> float:
    return 20.0 + OFFSETS[ablation] + 0.7 * SCENES.index(scene) + CHANNELS.index(channel) \
        + 0.1 * (len(ablation) % 3) * SCENES.index(scene)


def per_scene(psnr_of) -> dict:
    return {s: {**{c: {"psnr": psnr_of(s, c), "ssim": 0.5, "lpips": 0.2} for c in CHANNELS},
                "avg": {"psnr": -1.0, "ssim": 0.0, "lpips": 0.0}}  # ignored: recomputed
            for s in SCENES}


def baseline_psnr(scene: str, channel: str) -> float:
    return 15.0 + SCENES.index(scene)


def write_scores(folder: Path, ablation: str, *, scenes=SCENES, baseline=baseline_psnr, **extra) -> Path:
    folder.mkdir(parents=True)
    data = {"format": "gspi-points-eval", "version": 1, "ablation": ablation, "train_seed": 0,
            "data": "/data/heldout", "split": "test", "num_steps": 10, "scenes": list(scenes),
            "checkpoint_step": 500, "baseline_constants": {"roughness": 0.5, "metallic": 0.3},
            "per_scene": {"stage2": per_scene(lambda s, c: psnr(ablation, s, c)),
                          "no_decomposition": per_scene(baseline)}, **extra}
    (folder / "scores.json").write_text(json.dumps(data))
    return folder


def units(psnr_of) -> dict:
    return {(s, 0): float(np.mean([psnr_of(s, c) for c in CHANNELS])) for s in SCENES}


@pytest.fixture
def folders(tmp_path):
    for ablation in OFFSETS:
        write_scores(tmp_path / ablation / "eval", ablation)
    return tmp_path


def test_rows_cells_and_delta(folders):
    table = build_sweep_table(load_sources([folders], ("table2",)), TABLE_SPECS["table2"],
                              bootstrap={"n": 2000, "seed": 1})
    assert table.labels == ["No decomposition", "A1: w/o global semantic prior", "A3: N_pts = 1024",
                            "GS-PI (ours, Full)"]
    for ablation, label in (("full", "GS-PI (ours, Full)"), ("a1_no_global_prior", "A1: w/o global semantic prior")):
        values = np.array(list(units(lambda s, c: psnr(ablation, s, c)).values()))
        assert table.mean.loc[label, "psnr/avg"] == pytest.approx(values.mean())
        assert table.sem.loc[label, "psnr/avg"] == pytest.approx(values.std(ddof=1) / 2.0)
        assert table.count.loc[label, "psnr/avg"] == 4
    base = np.array(list(units(baseline_psnr).values()))
    assert table.mean.loc["No decomposition", "psnr/avg"] == pytest.approx(base.mean())
    expected = paired_bootstrap_ci(units(lambda s, c: psnr("a1_no_global_prior", s, c)),
                                   units(lambda s, c: psnr("full", s, c)), n_resamples=2000, seed=1)
    got = table.delta.loc["A1: w/o global semantic prior"]
    assert (got["mean"], got["lo"], got["hi"]) == pytest.approx(expected)
    assert got["mean"] == pytest.approx(-2.0 + 0.1 * 1.5 * (len("a1_no_global_prior") % 3 - len("full") % 3))


def test_gspi_table_says_the_measure_is_on_gt_point_clouds(folders, tmp_path):
    from omegaconf import OmegaConf

    from eval.tables.cli import run

    run(OmegaConf.create({"runs": [str(folders)], "out": str(tmp_path / "tables"), "table": "table2",
                          "bootstrap": {"n": 200, "seed": 0}}))
    text = (tmp_path / "tables" / "table2.md").read_text()
    assert "Table 2: Stage II ablations (GT point cloud, evaluate_points)" in text
    assert "GT point cloud (gspi.stage2.evaluate_points)" in text and "generated" not in text


def test_two_seeds_of_one_ablation_are_its_runs(folders):
    write_scores(folders / "full_seed1" / "eval", "full", train_seed=1)
    sweep = load_points_folders([folders])
    full = sweep.values[(sweep.values.method == "gspi") & (sweep.values.ablation == "full")]
    assert sorted(full.seed.unique()) == [0, 1]


def test_different_scene_sets_are_refused(folders):
    write_scores(folders / "other" / "eval", "a1_no_global_prior", scenes=SCENES[:3])
    with pytest.raises(ValueError, match="different scenes"):
        load_points_folders([folders])


def test_different_baselines_are_refused(folders):
    write_scores(folders / "other" / "eval", "a1_no_global_prior", baseline=lambda s, c: 9.0)
    with pytest.raises(ValueError, match="no-decomposition baseline differs"):
        load_points_folders([folders])


def test_scores_of_other_input_bytes_are_refused_by_their_checksums(folders):
    """Two measures of the same scenes on rebuilt data (same baseline to the digit, other bytes):
    the recorded input checksums name the scenes that differ; scores without checksums (measured
    before session 27) fall back to the other checks."""
    sums = lambda **changed: {"inputs": "x" + "".join(changed), "per_scene": {s: changed.get(s, "c") for s in SCENES}}  # noqa: E731
    write_scores(folders / "one" / "eval", "full", train_seed=1, checksums=sums())
    load_points_folders([folders])  # one measure with checksums among measures without: accepted
    write_scores(folders / "two" / "eval", "full", train_seed=2, checksums=sums(**{SCENES[1]: "d"}))
    with pytest.raises(ValueError, match=rf"input checksums differ for 1 scene\(s\), e\.g\. {SCENES[1]}: the data was rebuilt"):
        load_points_folders([folders])


def test_missing_field_names_the_file(tmp_path):
    folder = write_scores(tmp_path / "x", "full")
    data = json.loads((folder / "scores.json").read_text())
    del data["ablation"]
    (folder / "scores.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"x/scores.json: lacks 'ablation'"):
        load_points_folders([tmp_path])


def test_mixed_with_gspi_eval_folders_is_refused(folders):
    ev = folders / "plain_eval"
    ev.mkdir()
    (ev / "summary.json").write_text("{}")
    (ev / "eval_meta.json").write_text(json.dumps({"method": "no_decomposition"}))
    with pytest.raises(ValueError, match="tabulate them separately"):
        load_sources([folders], ("table2",))


def test_two_measures_are_never_tabulated_together(tmp_path):
    """Scores of one DDIM step count and point subset but another measure knob (here the number of
    samples averaged: eval.points_protocol's hash) are refused, like other scenes or data."""
    write_scores(tmp_path / "full" / "eval", "full")
    write_scores(tmp_path / "a1" / "eval", "a1_no_global_prior", num_samples=4)
    with pytest.raises(ValueError, match="measure .eval.points_protocol hash."):
        load_points_folders([tmp_path])
