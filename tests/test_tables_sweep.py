"""gspi-table on sweeps: run records -> Tables 1-3 with mean ± SE, Δ [CI], per-scene breakdown.

Fake sweeps are written in tmp_path with known per-scene numbers; every expected cell is
recomputed here with plain numpy from those numbers.
"""
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from omegaconf import OmegaConf

from eval.stats import paired_bootstrap_ci
from eval.sweep import SweepError, load_sweep, read_record
from eval.tables.cli import run
from eval.common.atomic import write_text_atomic
from eval.tables.render import per_scene_markdown, to_csv, to_latex, to_markdown
from eval.tables.build import TABLE_SPECS, build_sweep_table

SCENES = ("s0", "s1", "s2")
SEEDS = (0, 1)
MATERIAL = ("albedo", "roughness", "metallic")
# Table 2 variants and their PSNR offset from the full model (dB): ranks are known.
T2_OFFSETS = {"full": 0.0, "a1_no_global_prior": -6.0, "a2_no_view_onehot": -1.0,
              "a3_npts_1024": -2.0, "a4_npts_1024_nlat_384": -9.0,
              "a5_multiview_injection": -7.0}


def scores(ablation: str, scene: str, seed: int, channel: str, offset: float) -> tuple:
    """Deterministic (psnr, ssim, lpips) of one unit and channel, in file units."""
    h = (SCENES.index(scene) * 7 + seed * 3 + (MATERIAL + ("relight",)).index(channel)
         + sum(map(ord, ablation))) % 11
    return (25.0 + offset + 0.3 * h, 0.7 + 0.01 * offset + 0.005 * h,
            0.05 - 0.002 * offset + 0.001 * h)


def per_scene(ablation, seed, offset, channels=MATERIAL):
    return {s: {c: dict(zip(("psnr", "ssim", "lpips"), scores(ablation, s, seed, c, offset)))
                for c in channels} for s in SCENES}


def write_job(root: Path, name: str, *, method="gspi", ablation="full", table="table2", seed=0,
              config_hash=None, status="complete", error=None, offset=0.0, measure="points",
              channels=MATERIAL, runtime=(5.0, 10.0), protocol_version=1, data="data/tiny",
              protocol_config=None) -> Path:
    """One Hydra job folder with its evaluation folder(s) and result.json (written last)."""
    job = root / name
    (job / ".hydra").mkdir(parents=True)
    record = {"format": "gspi-run", "format_version": 1, "status": status, "error": error,
              "method": method, "ablation": ablation, "table": table, "seed": seed,
              "config_hash": config_hash or f"h-{method}-{ablation}-{seed}", "data": data,
              "scenes": list(SCENES), "material_eval": None, "points_eval": None}
    if status == "complete":
        ps = per_scene(ablation, seed, offset, channels)
        if measure == "points":
            (job / "points_eval").mkdir()
            ps_avg = {s: dict(v, avg={"psnr": -999.0, "ssim": 0.0, "lpips": 9.0})  # ignored
                      for s, v in ps.items()}
            (job / "points_eval" / "points_summary.json").write_text(json.dumps(
                {"mean": {}, "per_scene": ps_avg}))
            record["points_eval"] = "points_eval"
        else:
            (job / "eval").mkdir()
            (job / "eval" / "summary.json").write_text(json.dumps({}))
            (job / "eval" / "eval_meta.json").write_text(json.dumps({
                "method": method, "protocol": {"name": "gspi-decoupled",
                                               "version": protocol_version},
                "per_scene": ps, **({"protocol_config": protocol_config} if protocol_config else {}),
                "runtime_min": {"material": runtime[0], "end_to_end": runtime[1]}}))
            record["material_eval"] = "eval"
    (job / "result.json").write_text(json.dumps(record))
    return job


def table2_sweep(root: Path, variants=T2_OFFSETS, seeds=SEEDS) -> Path:
    for i, (abl, off) in enumerate(variants.items()):
        for seed in seeds:
            write_job(root, f"{i}_{seed}", ablation=abl, seed=seed, offset=off)
    return root


def expected_units(ablation, offset, metric_index, scale=1.0, seeds=SEEDS):
    """{(scene, seed): mean over albedo/roughness/metallic} computed from `scores`."""
    return {(s, k): scale * float(np.mean([scores(ablation, s, k, c, offset)[metric_index]
                                           for c in MATERIAL]))
            for s in SCENES for k in seeds}


def _build(root, name="table2", **kw):
    return build_sweep_table(load_sweep([root]), TABLE_SPECS[name], bootstrap=kw or None)


class TestTable2:
    def test_cells_are_mean_and_se_over_scenes_and_seeds(self, tmp_path):
        table = _build(table2_sweep(tmp_path))
        for abl, off in T2_OFFSETS.items():
            label = table.labels[[r[1] for r in table.rows].index(abl)]
            for i, (metric, scale) in enumerate((("psnr", 1), ("ssim", 100), ("lpips", 100))):
                units = np.array(list(expected_units(abl, off, i, scale).values()))
                assert len(units) == 6
                assert table.mean.loc[label, f"{metric}/avg"] == pytest.approx(units.mean())
                assert table.sem.loc[label, f"{metric}/avg"] == pytest.approx(
                    units.std(ddof=1) / np.sqrt(6))
                assert table.count.loc[label, f"{metric}/avg"] == 6

    def test_paper_row_names_and_order(self, tmp_path):
        table = _build(table2_sweep(tmp_path))
        assert table.labels == ["A1: w/o global semantic prior",
                                "A2: w/o view-direction conditioning signal", "A3: N_pts = 1024",
                                "A4: N_pts = 1024, N_lat = 384",
                                "A5: Direct multi-view injection", "GS-PI (ours, Full)"]

    def test_best_and_second_marks(self, tmp_path):
        table = _build(table2_sweep(tmp_path))
        marks = table.marks["psnr/avg"]
        assert marks["GS-PI (ours, Full)"] == 1
        assert marks["A2: w/o view-direction conditioning signal"] == 2
        assert (marks == 0).sum() == 4
        assert table.marks["lpips/avg"]["GS-PI (ours, Full)"] == 1  # lower is better
        md = to_markdown(table, load_sweep([tmp_path]))
        full_row = next(line for line in md.splitlines() if line.startswith("| GS-PI (ours, Full)"))
        assert full_row.count("**") == 6 and "reference" in full_row
        tex = to_latex(table, load_sweep([tmp_path]))
        assert r"\cellcolor{BaselineBestCell}\textbf{" in tex
        assert r"\cellcolor{BaselineSecondCell}" in tex and r"N\_pts" in tex

    def test_delta_is_the_paired_bootstrap_against_full(self, tmp_path):
        table = _build(table2_sweep(tmp_path), n=2000, seed=3)
        abl, label = "a3_npts_1024", "A3: N_pts = 1024"
        expected = paired_bootstrap_ci(expected_units(abl, -2.0, 0),
                                       expected_units("full", 0.0, 0), n_resamples=2000, seed=3)
        got = table.delta.loc[label]
        assert (got["mean"], got["lo"], got["hi"]) == pytest.approx(expected)
        assert got["n_pairs"] == 6 and got["lo"] <= got["mean"] <= got["hi"]
        assert "Δ PSNR vs GS-PI (ours, Full) [95% CI]" in to_markdown(table, load_sweep([tmp_path]))

    def test_per_scene_breakdown_is_the_seed_mean(self, tmp_path):
        table = _build(table2_sweep(tmp_path))
        units = expected_units("a1_no_global_prior", -6.0, 0)
        for scene in SCENES:
            want = np.mean([units[(scene, k)] for k in SEEDS])
            got = table.per_scene.loc[scene, "A1: w/o global semantic prior"]
            assert got == pytest.approx(want)
        assert list(table.per_scene.columns) == table.labels
        assert per_scene_markdown(table).count("\n| s") == len(SCENES)

    def test_csv_has_separate_mean_sem_n(self, tmp_path):
        import io

        import pandas as pd
        table = _build(table2_sweep(tmp_path))
        frame = pd.read_csv(io.StringIO(to_csv(table)))
        assert {"psnr/avg/mean", "psnr/avg/sem", "psnr/avg/n", "delta_psnr/avg/lo"} <= set(frame)
        row = frame.set_index("ablation").loc["full"]
        assert row["psnr/avg/mean"] == pytest.approx(table.mean.loc["GS-PI (ours, Full)", "psnr/avg"])


class TestFailedKilledAndDuplicateJobs:
    def test_failed_and_killed_jobs_give_no_rows_and_are_reported(self, tmp_path):
        table2_sweep(tmp_path, {"full": 0.0, "a1_no_global_prior": -6.0})
        write_job(tmp_path, "failed", ablation="a2_no_view_onehot", status="failed",
                  error="CUDA out of memory")
        killed = tmp_path / "killed"
        (killed / ".hydra").mkdir(parents=True)
        (killed / "eval" / ".hydra").mkdir(parents=True)  # its gspi-eval, killed too
        (tmp_path / "0_0" / "eval" / ".hydra").mkdir(parents=True)  # a finished job's gspi-eval
        sweep = load_sweep([tmp_path])
        table = build_sweep_table(sweep, TABLE_SPECS["table2"])
        assert len(table.labels) == 2 and not any("A2" in label for label in table.labels)
        md = to_markdown(table, sweep)
        assert "failed job:" in md and "CUDA out of memory" in md
        assert "1 job folder(s) without result.json" in md and str(killed) in md

    def test_duplicate_record_is_one_run_newest_kept(self, tmp_path):
        table2_sweep(tmp_path, {"full": 0.0}, seeds=(0,))
        old = tmp_path / "0_0" / "result.json"
        os.utime(old, (1e9, 1e9))
        write_job(tmp_path / "rerun", "0_0", seed=0, offset=1.0)  # same identity, newer
        sweep = load_sweep([tmp_path])
        assert len(sweep.records) == 1 and sweep.records[0].path.parent.parent.name == "rerun"
        assert any("kept the newest" in n for n in sweep.notes)
        table = build_sweep_table(sweep, TABLE_SPECS["table2"])
        want = np.mean(list(expected_units("full", 1.0, 0, seeds=(0,)).values()))
        assert table.mean.loc["GS-PI (ours, Full)", "psnr/avg"] == pytest.approx(want)
        assert table.count.loc["GS-PI (ours, Full)", "psnr/avg"] == len(SCENES)

    def test_rerun_completes_the_table_with_no_loss_and_no_duplicates(self, tmp_path):
        first, second = tmp_path / "sweep1", tmp_path / "sweep2"
        variants = {"full": 0.0, "a1_no_global_prior": -6.0, "a2_no_view_onehot": -1.0}
        for i, (abl, off) in enumerate(variants.items()):
            for seed in SEEDS:
                if (abl, seed) == ("a1_no_global_prior", 1):
                    (first / f"{i}_{seed}" / ".hydra").mkdir(parents=True)  # killed
                elif (abl, seed) == ("a2_no_view_onehot", 0):
                    write_job(first, f"{i}_{seed}", ablation=abl, seed=seed, status="failed",
                              error="killed by OOM")
                else:
                    write_job(first, f"{i}_{seed}", ablation=abl, seed=seed, offset=off)
        partial = _build(first)
        assert partial.count.loc["A1: w/o global semantic prior", "psnr/avg"] == 3
        # the rerun repeats the whole sweep: done jobs again, the two missing ones first time
        table2_sweep(second, variants)
        sweep = load_sweep([first, second])
        full = build_sweep_table(sweep, TABLE_SPECS["table2"])
        assert len(full.labels) == 3 and len(sweep.records) == 6
        for abl, off in variants.items():
            label = full.labels[[r[1] for r in full.rows].index(abl)]
            units = np.array(list(expected_units(abl, off, 0).values()))
            assert full.count.loc[label, "psnr/avg"] == 6
            assert full.mean.loc[label, "psnr/avg"] == pytest.approx(units.mean())
        assert not sweep.failed and len(sweep.superseded) == 1
        md = to_markdown(full, sweep)
        assert "superseded by a complete rerun" in md and "failed job:" not in md

    def test_one_configuration_in_two_tables_is_two_runs(self, tmp_path):
        write_job(tmp_path, "t2", config_hash="same")
        write_job(tmp_path, "t3", config_hash="same", table="table3", measure="material")
        sweep = load_sweep([tmp_path])
        assert len(sweep.records) == 2 and not sweep.notes
        assert _build(tmp_path, "table3").labels == ["GS-PI (ours, Full)"]

    def test_two_configurations_of_one_run_are_refused(self, tmp_path):
        write_job(tmp_path, "a", config_hash="aaa")
        write_job(tmp_path, "b", config_hash="bbb")
        with pytest.raises(SweepError, match="two configurations"):
            load_sweep([tmp_path])


class TestRecordValidation:
    def test_bad_json_names_the_file(self, tmp_path):
        job = write_job(tmp_path, "j")
        (job / "result.json").write_text("{not json")
        with pytest.raises(SweepError, match=r"result\.json: invalid JSON"):
            load_sweep([tmp_path])

    def test_unknown_format_version(self, tmp_path):
        path = write_job(tmp_path, "j") / "result.json"
        path.write_text(json.dumps(dict(json.loads(path.read_text()), format_version=2)))
        with pytest.raises(SweepError, match="unknown record format 'gspi-run' version 2"):
            read_record(path)

    def test_missing_subfolder(self, tmp_path):
        job = write_job(tmp_path, "j")
        (job / "points_eval" / "points_summary.json").unlink()
        (job / "points_eval").rmdir()
        with pytest.raises(SweepError, match="points_eval names 'points_eval' but"):
            read_record(job / "result.json")

    def test_missing_key_and_missing_metric(self, tmp_path):
        path = write_job(tmp_path, "j") / "result.json"
        data = json.loads(path.read_text())
        path.write_text(json.dumps({k: v for k, v in data.items() if k != "seed"}))
        with pytest.raises(SweepError, match=r"missing key\(s\) \['seed'\]"):
            read_record(path)
        job = write_job(tmp_path, "k")
        summary = job / "points_eval" / "points_summary.json"
        summary.write_text(json.dumps({"per_scene": {"s0": {"albedo": {"psnr": 1.0}}}}))
        with pytest.raises(SweepError, match="per_scene.s0.albedo lacks 'ssim'"):
            load_sweep([job])


    def test_a_job_written_before_points_summary_json_is_still_read(self, tmp_path):
        """points_eval/summary.json (its name before session 12) reads as points_summary.json."""
        job = write_job(tmp_path, "j")
        want = load_sweep([job]).values
        (job / "points_eval" / "points_summary.json").rename(job / "points_eval" / "summary.json")
        got = load_sweep([job]).values
        pd.testing.assert_frame_equal(got.drop(columns=["run"], errors="ignore"),
                                      want.drop(columns=["run"], errors="ignore"))
        assert (got["measure"] == "points").sum() == (want["measure"] == "points").sum() > 0

class TestTables1And3:
    def test_table3_averages_material_eval_channels(self, tmp_path):
        for abl, off in {"full": 0.0, "a6_no_distill": -2.0, "a9_freeze_both": -0.5}.items():
            for seed in SEEDS:
                write_job(tmp_path, f"{abl}_{seed}", ablation=abl, seed=seed, offset=off,
                          table="table3", measure="material", channels=MATERIAL + ("relight",))
        table = _build(tmp_path, "table3")
        assert table.labels == ["A6: w/o distill", "A9: Freeze opacity & scaling", "GS-PI (ours, Full)"]
        units = np.array(list(expected_units("a6_no_distill", -2.0, 1, 100).values()))
        assert table.mean.loc["A6: w/o distill", "ssim/avg"] == pytest.approx(units.mean())
        assert table.marks.loc["A9: Freeze opacity & scaling", "psnr/avg"] == 2
        assert "Protocol: gspi-decoupled v1" in to_markdown(table, load_sweep([tmp_path]))
        assert r"Opacity \& scaling".lower() in to_latex(table, load_sweep([tmp_path])).lower()

    def test_table1_methods_missing_channels_and_runtime(self, tmp_path):
        write_job(tmp_path, "ours", table="table1", measure="material", offset=3.0,
                  channels=MATERIAL + ("relight",), runtime=(5.4, 10.4))
        write_job(tmp_path, "gsir", method="gs_ir", table="table1", measure="material",
                  channels=("albedo", "roughness", "relight"), runtime=(29.8, 34.4))
        write_job(tmp_path, "nodec", method="no_decomposition", table="table1",
                  measure="material", channels=("albedo", "relight"), offset=-1.0,
                  runtime=(0.1, 5.1))
        table = _build(tmp_path, "table1")
        assert table.labels == ["GS-IR", "No decomposition", "GS-PI (ours)"]
        assert np.isnan(table.mean.loc["GS-IR", "psnr/metallic"])
        assert table.mean.loc["GS-PI (ours)", "minutes/material"] == pytest.approx(5.4)
        assert table.marks.loc["No decomposition", "minutes/material"] == 1
        md = to_markdown(table, load_sweep([tmp_path]))
        nodec = next(line for line in md.splitlines() if line.startswith("| No decomposition"))
        assert nodec.count("| -- ") == 6 and "0.1" in nodec
        assert "Δ PSNR relight vs GS-PI (ours)" in md
        d = paired_bootstrap_ci(
            {(s, 0): scores("full", s, 0, "relight", -1.0)[0] for s in SCENES},
            {(s, 0): scores("full", s, 0, "relight", 3.0)[0] for s in SCENES})
        assert table.delta.loc["No decomposition", "mean"] == pytest.approx(d[0])

    def test_mixed_protocols_are_refused(self, tmp_path):
        write_job(tmp_path, "a", table="table3", measure="material")
        write_job(tmp_path, "b", table="table3", measure="material", ablation="a7_freeze_opacity",
                  protocol_version=2)
        with pytest.raises(ValueError, match="different protocols"):
            _build(tmp_path, "table3")


class TestCommand:
    def _cfg(self, runs, out, **extra):
        return OmegaConf.create({"runs": [str(r) for r in runs], "out": str(out), "table": None,
                                 "bootstrap": {"n": 500, "seed": 0, "confidence": 0.95},
                                 **extra})

    def test_writes_every_file_atomically_and_prints(self, tmp_path, capsys):
        sweep = table2_sweep(tmp_path / "sweep", {"full": 0.0, "a1_no_global_prior": -6.0})
        write_job(sweep, "t3", ablation="a7_freeze_opacity", table="table3", measure="material")
        write_job(sweep, "t3f", table="table3", measure="material")
        out = tmp_path / "tables"
        built = run(self._cfg([sweep], out))
        assert set(built) == {"table2", "table3"}
        names = sorted(p.name for p in out.iterdir())
        assert names == sorted(f"{t}{s}" for t in ("table2", "table3")
                               for s in (".md", ".tex", ".csv", "_per_scene.md",
                                         "_per_scene.csv"))  # no temp files left
        assert "### Table 2" in capsys.readouterr().out

    def test_table_option_picks_one(self, tmp_path):
        sweep = table2_sweep(tmp_path / "sweep", {"full": 0.0, "a1_no_global_prior": -6.0})
        write_job(sweep, "t3", table="table3", measure="material")
        assert set(run(self._cfg([sweep], tmp_path / "o", table="table2"))) == {"table2"}
        with pytest.raises(ValueError, match="table='table9'"):
            run(self._cfg([sweep], tmp_path / "o", table="table9"))

    def test_sweep_of_only_killed_jobs_is_an_error_not_an_old_style_table(self, tmp_path):
        job = tmp_path / "sweep" / "0"
        (job / ".hydra").mkdir(parents=True)
        (job / "eval").mkdir()
        (job / "eval" / "summary.json").write_text("{}")  # a half-done evaluation
        with pytest.raises(ValueError, match="1 job folder"):
            run(self._cfg([tmp_path / "sweep"], tmp_path / "o"))

    def test_plain_gspi_eval_folders_still_give_table1(self, tmp_path):
        d = tmp_path / "eval_a"
        (d / ".hydra").mkdir(parents=True)  # gspi-eval is a Hydra app: not a killed sweep job
        (d / "summary.json").write_text(json.dumps(
            {c: {"psnr": 20.0, "ssim": 0.8, "lpips": 0.05} for c in MATERIAL + ("relight",)}))
        (d / "eval_meta.json").write_text(json.dumps(
            {"method": "A", "protocol": {"name": "p", "version": 1}}))
        table = run(self._cfg([d], tmp_path / "o"))["table1"]
        assert table.mean.loc["A", "psnr/albedo"] == 20.0
        assert (tmp_path / "o" / "table1.md").is_file()

    def test_config_composes_with_its_options(self, tmp_path):
        from hydra import compose, initialize_config_dir

        from eval.common.conf import CONF_DIR
        with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
            cfg = compose("gspi_table", overrides=["table=table3", "bootstrap.n=123"])
        assert cfg.table == "table3" and cfg.bootstrap.n == 123 and cfg.bootstrap.seed == 0


def test_atomic_write_keeps_the_old_file_when_interrupted(tmp_path, monkeypatch):
    path = tmp_path / "t.md"
    write_text_atomic(path, "old\n")

    def killed(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        write_text_atomic(path, "new\n")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["t.md"]


def test_table3_from_real_gspi_eval_folders(sphere_dataset, tmp_path, lpips_net):
    """Real eval_meta.json files: cells equal the per-scene means of per_view.csv; an
    identical channel scores the PSNR cap, so cells and Δ stay finite; the footer counts it."""
    import pandas as pd

    from eval.evaluate import evaluate
    from eval.records.eval_folder import write_result
    from tests.fixtures import make_prediction, protocol

    prot = protocol(channels=["albedo", "roughness", "metallic"])
    expected = {}
    for ablation, albedo_scale in (("full", 1.0), ("a6_no_distill", 0.8)):
        for seed in (0, 1):
            job = tmp_path / "sweep" / f"{ablation}_{seed}"
            pred = make_prediction(sphere_dataset, job / "predictions",
                                   albedo_scale=albedo_scale,
                                   roughness_offset=(6554 + 655 * seed) / 65535)
            write_result(job / "eval", evaluate(sphere_dataset, pred, prot, net=lpips_net))
            (job / "result.json").write_text(json.dumps({
                "format": "gspi-run", "format_version": 1, "status": "complete", "error": None,
                "method": "gspi", "ablation": ablation, "table": "table3", "seed": seed,
                "config_hash": f"{ablation}{seed}", "data": str(sphere_dataset), "scenes": [],
                "material_eval": "eval", "points_eval": None}))
            rows = pd.read_csv(job / "eval" / "per_view.csv")
            per_scene = rows.groupby(["scene", "channel"])["ssim"].mean().groupby("scene").mean()
            expected.setdefault(ablation, []).extend(100 * per_scene.to_numpy())
    sweep = load_sweep([tmp_path / "sweep"])
    minutes = sweep.values[(sweep.values["measure"] == "runtime")
                           & (sweep.values["channel"] == "material")]
    assert len(minutes) == 8 and (minutes["value"] == 1.0).all()  # pred meta.json: 60 s a scene
    table = build_sweep_table(sweep, TABLE_SPECS["table3"], bootstrap={"n": 200})
    for ablation, label in (("full", "GS-PI (ours, Full)"), ("a6_no_distill", "A6: w/o distill")):
        units = np.array(expected[ablation])
        assert table.mean.loc[label, "ssim/avg"] == pytest.approx(units.mean(), rel=1e-9)
        assert table.sem.loc[label, "ssim/avg"] == pytest.approx(
            units.std(ddof=1) / np.sqrt(len(units)), rel=1e-9)
    # metallic is copied exactly: PSNR at the documented cap (107.12 dB), never inf
    cap = 10 * np.log10(12 * 65535.0**2)
    psnr = pd.concat(pd.read_csv(tmp_path / "sweep" / f"full_{s}" / "eval" / "per_view.csv")
                     for s in (0, 1))
    assert np.allclose(psnr.loc[psnr["channel"] == "metallic", "psnr"], cap, rtol=0, atol=1e-9)
    assert np.isfinite(table.mean.loc["GS-PI (ours, Full)", "psnr/avg"])
    assert table.count.loc["GS-PI (ours, Full)", "psnr/avg"] == 4  # 2 scenes x 2 seeds
    md = to_markdown(table, sweep)
    assert "inf" not in md.replace("info", "")
    assert not np.isnan(table.delta.loc["A6: w/o distill", "mean"])
    assert "gspi-decoupled v1 #" in md and "LPIPS alex v0.1 masked_mean" in md
    # 4 runs x 2 scenes x 3 test views each; metallic copied everywhere, albedo exact in the
    # 2 "full" runs (scale 1.0), roughness always offset
    assert "metallic 24 (24 at PSNR floor" in md and "albedo 24 (12 at PSNR floor)" in md
    assert "roughness 24 (0 at PSNR floor)" in md
    assert list(table.per_scene.index) == ["sphere_0", "sphere_1"]


def test_row_labels_come_from_the_paper_ids():
    from eval.tables.labels import row_label, row_order
    assert row_label("gspi", "a9_freeze_both", "table3") == "A9: Freeze opacity & scaling"
    assert row_label("gspi", "a9_freeze_opacity_scaling", "table3") == \
        "A9: Freeze opacity & scaling"
    assert row_label("gspi", "a10_new_idea", "table3") == "a10_new_idea"  # never dropped
    assert row_label("no_decomposition", "full", "table2") == "No decomposition"
    assert row_label("gs_ir", "full", "table1") == "GS-IR"
    assert row_label("gspi", "a6_no_distill", "table1") == "GS-PI (ours) [a6_no_distill]"
    rows = [("gspi", "full"), ("gspi", "a2_x"), ("gs_ir", "full"), ("gspi", "a1_y")]
    assert sorted(rows, key=lambda r: row_order(*r)) == \
        [("gs_ir", "full"), ("gspi", "a1_y"), ("gspi", "a2_x"), ("gspi", "full")]


def test_sweep_mixing_two_conventions_is_refused_naming_runs_and_keys(tmp_path):
    base = {"name": "gspi-decoupled", "version": 1, "relight": {"tonemap": "aces"}}
    a = write_job(tmp_path / "sweep", "a", table="table3", measure="material", protocol_config=base)
    b = write_job(tmp_path / "sweep", "b", table="table3", measure="material", seed=1,
                  protocol_config=dict(base, relight={"tonemap": "clamp"}))
    with pytest.raises(ValueError) as err:
        build_sweep_table(load_sweep([tmp_path / "sweep"]), TABLE_SPECS["table3"])
    text = str(err.value)
    assert "different protocols" in text and "relight.tonemap: 'aces' != 'clamp'" in text
    assert str(a) in text and str(b) in text


def test_one_row_on_two_datasets_is_refused_naming_runs(tmp_path):
    a = write_job(tmp_path / "sweep", "a", table="table3", measure="material", data="data/small")
    b = write_job(tmp_path / "sweep", "b", table="table3", measure="material", seed=1,
                  data="data/tiny")
    with pytest.raises(ValueError, match="different datasets") as err:
        build_sweep_table(load_sweep([tmp_path / "sweep"]), TABLE_SPECS["table3"])
    assert str(a) in str(err.value) and str(b) in str(err.value)


class TestNaturalAblationSweep:
    """`gspi-run -m ablation=full,a1_no_global_prior,a6_no_distillation` (no experiment): its Full
    run records `table: null` and is the reference row of Tables 2 and 3 (issue 54)."""

    @staticmethod
    def natural_sweep(root: Path) -> Path:
        for seed in SEEDS:
            full = write_job(root, f"full_{seed}", table=None, seed=seed, measure="points")
            material = write_job(root.parent / "scratch", f"full_{seed}", table=None, seed=seed,
                                 measure="material")
            (material / "eval").rename(full / "eval")  # a gspi-run Full job scores both
            record = json.loads((full / "result.json").read_text())
            (full / "result.json").write_text(json.dumps(dict(record, material_eval="eval")))
            write_job(root, f"a1_{seed}", ablation="a1_no_global_prior", table=None, seed=seed,
                      offset=-6.0, measure="points")
            write_job(root, f"a6_{seed}", ablation="a6_no_distillation", table=None, seed=seed,
                      offset=-2.0, measure="material")
        return root

    def test_tables_2_and_3_get_the_reference_row_delta_and_ci(self, tmp_path):
        root = self.natural_sweep(tmp_path / "sweep")
        for name, label in (("table2", "A1: w/o global semantic prior"), ("table3", "A6: w/o distill")):
            table = _build(root, name, n=200)
            assert table.reference == "GS-PI (ours, Full)" and table.labels[-1] == "GS-PI (ours, Full)", table.labels
            lo, mean, hi = (table.delta.loc[label, k] for k in ("lo", "mean", "hi"))
            assert lo <= mean <= hi and mean < 0 and table.delta.loc[label, "n_pairs"] == 6
        assert _build(root, "table1").labels == ["GS-PI (ours)"]  # Table 1 keeps its row too

    def test_a_table_with_its_own_full_keeps_it(self, tmp_path):
        root = self.natural_sweep(tmp_path / "sweep")
        for seed in SEEDS:
            write_job(tmp_path / "t2", f"full_{seed}", table="table2", seed=seed, config_hash=f"t2-{seed}")
        sweep = load_sweep([root, tmp_path / "t2"])
        fulls = [r for r in sweep.records if r.table == "table2" and r.ablation == "full"]
        assert sorted(r.config_hash for r in fulls) == ["t2-0", "t2-1"]

    def test_two_configs_of_one_row_name_the_differing_keys(self, tmp_path):
        for name, table, ckpt in (("plain", None, "checkpoints/x.pt"), ("t2", "table2", None)):
            job = write_job(tmp_path / name, "a1", ablation="a1_no_global_prior", table=table,
                            config_hash=f"h-{name}")
            (job / ".hydra" / "config.yaml").write_text(
                f"table: {table or 'null'}\nout: {job}\nstage2:\n  checkpoint: {ckpt or 'null'}\n  lr: 0.001\n")
        with pytest.raises(SweepError) as exc:
            load_sweep([tmp_path])
        message = str(exc.value)
        assert "table: None vs 'table2'" in message or "table: 'table2' vs None" in message, message
        assert "stage2.checkpoint" in message and "stage2.lr" not in message and "out:" not in message


def test_rows_of_failed_and_killed_jobs_are_named(tmp_path, capsys):
    """A row whose every job failed, or was killed before its record, is named (footer and one
    stderr line), not silently left out; a row with one failed seed says it is shown from the rest."""
    table2_sweep(tmp_path, {"full": 0.0, "a1_no_global_prior": -6.0})
    write_job(tmp_path, "a2", ablation="a2_no_view_onehot", status="failed", error="boom")
    write_job(tmp_path, "a1_s2", ablation="a1_no_global_prior", seed=2, status="failed", error="oom")
    killed = tmp_path / "a3"
    (killed / ".hydra").mkdir(parents=True)
    (killed / ".hydra" / "config.yaml").write_text(
        "method:\n  name: gspi\nablation_name: a3_npts_1024\ntable: table2\nseed: 0\n")
    cfg = OmegaConf.create({"runs": [str(tmp_path)], "out": str(tmp_path / "tables"), "table": "table2",
                            "bootstrap": {"n": 100}})
    run(cfg)
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if line.startswith("gspi-table: warning: table2: ")]
    assert len(warning) == 1, err
    text = warning[0]
    assert "A2: w/o view-direction conditioning signal (method=gspi ablation=a2_no_view_onehot: " \
           "1 failed job(s), missing from the table" in text
    assert "A3: N_pts = 1024 (method=gspi ablation=a3_npts_1024: 1 job(s) without result.json, " \
           "missing from the table" in text and str(killed) in text
    assert "A1: w/o global semantic prior (method=gspi ablation=a1_no_global_prior: 1 failed job(s), " \
           "shown from its complete runs only" in text
    md = (tmp_path / "tables" / "table2.md").read_text()
    assert "rows with failed or unfinished jobs: A1: w/o global" in md
