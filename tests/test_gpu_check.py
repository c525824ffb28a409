"""benchmarks/gpu_check.py --smoke: every step of the one-shot GPU check at tiny size on the CPU."""
from __future__ import annotations

import json

import pytest
import torch

from benchmarks.gpu_check import STEPS, main


def test_smoke_runs_every_step_and_writes_one_json(tmp_path):
    out = tmp_path / "out"
    report = main(["--smoke", "--out", str(out), "--work", str(tmp_path / "work")])
    saved = json.loads((out / "gpu_check.json").read_text())
    assert saved["mode"] == "smoke" and saved["skipped"] == []
    assert list(saved["steps"]) == [name for name, _ in STEPS]
    errors = {k: v["error"] for k, v in saved["steps"].items() if v.get("error")}
    assert not errors, errors
    e2e = saved["steps"]["e2e_tiny"]
    assert e2e["cpu"]["status"] == "complete" and "eval.albedo.psnr" in e2e["cpu"]["numbers"]
    assert saved["steps"]["stage2_train_throughput"]["points_per_s"] > 0
    assert saved["steps"]["stage2_sampling_linearity"]["ratio_10N_over_N"] > 0
    data_eval = saved["steps"]["data_eval_cuda"]  # the CPU half: gspi-data, then its own oracle
    assert data_eval["eval_cpu"]["albedo.psnr"] > 100 and data_eval["cuda"] == {"skipped": "no CUDA"}
    stages = saved["steps"]["paper_scene"]["stages"]
    assert {"recon", "stage1", "stage2", "stage3"} <= set(stages)
    burst = saved["steps"]["stage2_train_burst"]
    assert burst["steps"] == 3 and (out / "stage2_burst_ema.pt").is_file()
    assert torch.load(out / "stage2_burst_ema.pt", weights_only=True)["weights"] == "ema-fp16"
    assert (out / "gpu_check.log").stat().st_size > 0 and report["total_seconds"] > 0


def test_budget_skips_the_remaining_steps_and_records_them(tmp_path):
    saved = main(["--smoke", "--out", str(tmp_path / "out"), "--budget-s", "0",
                  "--only", "stage2_train_throughput,stage2_sampling_linearity"])
    assert saved["steps"] == {}
    assert [s["step"] for s in saved["skipped"]] == ["stage2_train_throughput", "stage2_sampling_linearity"]


def test_gpu_mode_without_cuda_is_one_clear_error(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("CUDA is present")
    with pytest.raises(ValueError, match="gpu_check.*CUDA is not available"):
        main(["--out", str(tmp_path / "out")])
