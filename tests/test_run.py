"""The end-to-end runner (gspi-run): records, skip/resume, failure capture, a tiny real run."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from gspi.run.record import config_hash, is_complete, read_result, write_result
from gspi.stage_clock import StageClock
from gspi.stage2.infer import nearest_fill, subsample_indices

from tests.run_helpers import run_config


def test_config_hash_ignores_volatile_keys_only():
    cfg = {"out": "a", "threads": 1, "seed": 0, "stage3": {"iterations": 5}, "logger": {"name": "none"}}
    assert config_hash(cfg) == config_hash({**cfg, "out": "b", "threads": 4, "logger": {"name": "wandb"}})
    assert config_hash(cfg) != config_hash({**cfg, "seed": 1})
    assert config_hash(cfg) != config_hash({**cfg, "stage3": {"iterations": 6}})


def test_result_record_round_trip_and_completeness(tmp_path):
    assert read_result(tmp_path) is None and not is_complete(tmp_path, "h")
    write_result(tmp_path, status="failed", cfg_hash="h", method="gspi", ablation="full", table=None, seed=0,
                 data="d", scenes=["s"], error="boom")
    assert read_result(tmp_path)["error"] == "boom" and not is_complete(tmp_path, "h")
    write_result(tmp_path, status="complete", cfg_hash="h", method="gspi", ablation="full", table="table3",
                 seed=0, data="d", scenes=["s"], material_eval="eval")
    assert is_complete(tmp_path, "h") and not is_complete(tmp_path, "other")
    (tmp_path / "result.json").write_text("{half")  # a torn file is "no result", never a crash
    assert read_result(tmp_path) is None
    with pytest.raises(ValueError, match="status"):
        write_result(tmp_path, status="ok", cfg_hash="h", method="m", ablation="a", table=None, seed=0,
                     data="d", scenes=[])


def test_stage_clock_records_time_and_memory():
    clock = StageClock("s")
    with clock.stage("alloc"):
        block = np.ones((64, 2**20 // 8))  # 64 MB
        block += 1
    info = clock.stages["alloc"]
    assert info["seconds"] >= 0 and info["peak_rss_mb"] > 64
    assert clock.seconds("alloc", "absent") == info["seconds"]


def test_stage_clock_cpu_time_counts_work_not_waiting():
    """A stage that sleeps takes wall time and almost no CPU time; one that computes takes both."""
    import time

    clock = StageClock("s")
    with clock.stage("sleep"):
        time.sleep(0.3)
    with clock.stage("work"):
        c0 = time.process_time()
        while time.process_time() - c0 < 0.2:
            sum(i * i for i in range(1000))
    sleep, work = clock.stages["sleep"], clock.stages["work"]
    assert sleep["seconds"] >= 0.3 and sleep["cpu_seconds"] < 0.1
    assert work["cpu_seconds"] >= 0.2 and work["cpu_seconds"] <= work["seconds"] + 0.05  # one thread


def test_subsample_and_nearest_fill():
    assert subsample_indices(10, None, 0) is None and subsample_indices(10, 20, 0) is None
    idx = subsample_indices(100, 10, seed=3)
    assert len(idx) == 10 and np.array_equal(idx, subsample_indices(100, 10, seed=3))
    xyz_sub = np.array([[0.0, 0, 0], [1, 0, 0]])
    values = np.array([[1.0], [2.0]])
    filled = nearest_fill(xyz_sub, values, np.array([[0.1, 0, 0], [0.9, 0, 0], [0.49, 0, 0]]))
    assert filled[:, 0].tolist() == [1.0, 2.0, 1.0]


def test_x0_head_is_read_as_eps_consistently():
    """With prediction=x0, the sampler's f0 estimate from the returned eps IS the head's output."""
    from gspi.stage2.inputs import Stage2Inputs
    from gspi.stage2.model import RCWConfig, RCWDenoiser
    from gspi.stage2.schedule import predict_f0_from_eps

    torch.manual_seed(0)
    cfg = RCWConfig(num_latents=4, latent_dim=16, point_dim=16, num_blocks=1, num_compute_layers=1, num_heads=2,
                    global_token_dim=0, prediction="x0")
    model = RCWDenoiser(cfg).double()
    inputs = Stage2Inputs(xyz=torch.randn(2, 30, 3).double(), local_cond=torch.rand(2, 30, 35).double(),
                          global_tokens=None)
    f_t, t = torch.randn(2, 30, 5).double(), torch.tensor([10, 900])
    eps = model(f_t, t, inputs).eps
    eps_head = RCWDenoiser(RCWConfig(**{**cfg.__dict__, "prediction": "eps"})).double()
    eps_head.load_state_dict(model.state_dict())
    head = eps_head(f_t, t, inputs).eps
    assert torch.allclose(predict_f0_from_eps(f_t, t, eps), head, atol=1e-6)
    with pytest.raises(ValueError, match="prediction"):
        RCWConfig(prediction="v")


def test_tiny_end_to_end_run_then_rerun_skips(micro_dataset, tmp_path):
    """Stage 0 -> I -> II (trained here) -> III -> eval on a 32-px scene; a rerun skips the job."""
    from gspi.run.runner import run_job

    cfg = run_config(micro_dataset, tmp_path / "run")
    result = run_job(cfg)
    assert result["status"] == "complete", result
    test_scene = json.loads((micro_dataset / "splits.json").read_text())["test"][0]
    out = tmp_path / "run"
    meta = json.loads((out / "predictions" / test_scene / "meta.json").read_text())
    assert meta["method"] == "gspi" and set(meta["stages"]) >= {"recon", "stage1", "stage2", "stage3", "render"}
    assert meta["runtime_s"]["material"] > 0 and meta["runtime_s"]["end_to_end"] >= meta["runtime_s"]["material"]
    summary = json.loads((out / "eval" / "summary.json").read_text())
    assert set(summary) == {"albedo", "roughness", "metallic", "relight"}
    points = json.loads((out / "points_eval" / "points_summary.json").read_text())
    assert set(points["per_scene"]) == {test_scene} and "avg" in points["mean"]
    assert (out / "work" / test_scene / "pbr_gs.ply").is_file() and (out / "figures" / f"{test_scene}.png").is_file()
    eval_meta = json.loads((out / "eval" / "eval_meta.json").read_text())
    assert result["protocol_hash"] == eval_meta["protocol"]["hash"]  # the record names what it scored
    assert {k: result["checksums"][k] for k in ("predictions", "ground_truth")} == \
        {k: eval_meta["checksums"][k] for k in ("predictions", "ground_truth")}
    assert eval_meta["peak_memory_mb"]["rss"] >= max(s["peak_rss_mb"] for s in meta["stages"].values())
    stamp = (out / "result.json").stat().st_mtime_ns
    assert run_job(cfg)["status"] == "complete"
    assert (out / "result.json").stat().st_mtime_ns == stamp  # skipped, not redone


def test_failed_scene_is_recorded_and_rerun_redoes_only_it(micro_dataset, tmp_path):
    from gspi.run.runner import run_job

    out = tmp_path / "run"
    bad = run_config(micro_dataset, out, ["method=no_decomposition", "assets=/nonexistent/assets"])
    result = run_job(bad, reraise=False)
    assert result["status"] == "failed" and "/nonexistent/assets" in result["error"]
    with pytest.raises(RuntimeError, match="scenes failed"):
        run_job(bad, reraise=True)
    good = run_config(micro_dataset, out, ["method=no_decomposition"])
    assert run_job(good)["status"] == "complete"


def _prediction_bytes(pred: Path) -> dict:
    return {str(p.relative_to(pred)): p.read_bytes() for p in sorted(pred.rglob("*.png"))}


def test_scene_workers_give_the_serial_predictions_and_isolate_a_failure(micro_dataset, tmp_path):
    """scene_workers=2 runs scenes in spawned processes: the same files as a serial run, the
    config hash unchanged, and a scene failing in a worker recorded while the others finish."""
    import shutil

    from gspi.run.runner import run_job

    scenes = sorted(p.parent.name for p in micro_dataset.glob("*/scene.json"))
    assert len(scenes) == 3
    pick = [f"scenes=[{','.join(scenes)}]"]
    serial = run_config(micro_dataset, tmp_path / "serial", pick)
    parallel = run_config(micro_dataset, tmp_path / "parallel", pick + ["scene_workers=2"])
    assert config_hash(serial) == config_hash(parallel)
    assert run_job(serial)["status"] == "complete"
    assert run_job(parallel)["status"] == "complete"
    a, b = _prediction_bytes(tmp_path / "serial" / "predictions"), _prediction_bytes(tmp_path / "parallel" / "predictions")
    assert len(a) == 3 * 2 * 3 and a == b  # scenes x test views x maps, byte for byte

    # One scene's asset missing: that scene fails in its worker, the other two are predicted.
    assets = tmp_path / "assets"
    for name in scenes[1:]:
        (assets / name).mkdir(parents=True)
        used = json.loads((tmp_path / "serial" / "predictions" / name / "meta.json").read_text())["asset"]["path"]
        shutil.copy(used, assets / name / "point_cloud.ply")
    cfg = run_config(micro_dataset, tmp_path / "broken", pick + ["scene_workers=2", f"assets={assets}",
                                                                 "method=no_decomposition"])
    result = run_job(cfg, reraise=False)
    assert result["status"] == "failed" and list(result["scene_errors"]) == [scenes[0]], result
    assert scenes[0] in result["error"]
    for name in scenes[1:]:
        assert (tmp_path / "broken" / "predictions" / name / "meta.json").is_file()


def test_scene_workers_inside_a_joblib_sweep_worker(micro_dataset, tmp_path):
    """`hydra/launcher=joblib` runs each job in a loky worker; its scene workers must start there
    (a plain multiprocessing spawn cannot resolve loky's start method and every scene died)."""
    from joblib import Parallel, delayed

    from gspi.run.runner import run_job

    scenes = sorted(p.parent.name for p in micro_dataset.glob("*/scene.json"))
    cfg = run_config(micro_dataset, tmp_path / "job", [f"scenes=[{','.join(scenes)}]", "scene_workers=2",
                                                       "method=no_decomposition"])
    (result,) = Parallel(n_jobs=2, backend="loky")(delayed(run_job)(cfg, reraise=False) for _ in range(1))
    assert result["status"] == "complete" and result["scene_errors"] == {}, result
    assert all((tmp_path / "job" / "predictions" / name / "meta.json").is_file() for name in scenes)


def test_a_user_asset_that_does_not_match_the_photos_is_flagged(micro_dataset, tmp_path):
    """asset_check (issue 41): a flat green sphere run on a scene whose photos it does not show
    is recorded below asset_check.min_psnr with a one-line warning naming the PLY, shown on the
    report's scene page; asset_check.strict=true fails the scene instead."""
    from eval.common.layout import read_scene, read_splits
    from eval.report_site.collect import Job
    from eval.report_site.scene_page import SceneWriter
    from gspi.gaussians.ply import write_ply
    from gspi.run.runner import run_job
    from tests.fixtures import surfel_sphere

    flat = tmp_path / "flat_green_sphere.ply"
    write_ply(flat, surfel_sphere(2000, radius=0.8, color=(0.05, 0.9, 0.05)))
    name = read_splits(micro_dataset)["test"][0]
    out = tmp_path / "loose"
    result = run_job(run_config(micro_dataset, out, ["method=no_decomposition", f"assets={flat}"]))
    assert result["status"] == "complete", result
    check = json.loads((out / "predictions" / name / "meta.json").read_text())["asset"]["asset_check"]
    assert check["passed"] is False and check["psnr_masked"] < check["min_psnr"] == 10.0, check
    assert str(flat) in check["warning"] and "may not depict this scene" in check["warning"]
    job = Job(run_dir=out, method="no_decomposition", ablation="full", table="table1", seed=0,
              label="No decomposition", data=micro_dataset, predictions=out / "predictions", eval_dir=None,
              scenes=(name,))
    html = SceneWriter(tmp_path / "site", read_scene(micro_dataset / name), [job], thumb=16, quality=50).asset_checks()
    assert "Warning" in html and f"{check['psnr_masked']:.2f} dB" in html
    # the same asset with a threshold below its score passes, and is shown without a warning
    ok = run_config(micro_dataset, tmp_path / "lenient", ["method=no_decomposition", f"assets={flat}",
                                                           "asset_check.min_psnr=0"])
    assert run_job(ok)["status"] == "complete"
    meta = json.loads((tmp_path / "lenient" / "predictions" / name / "meta.json").read_text())
    assert meta["asset"]["asset_check"]["passed"] is True and "warning" not in meta["asset"]["asset_check"]
    strict = run_config(micro_dataset, tmp_path / "strict", ["method=no_decomposition", f"assets={flat}",
                                                              "asset_check.strict=true"])
    failed = run_job(strict, reraise=False)
    assert failed["status"] == "failed" and "asset_check.strict=true" in failed["error"], failed
