"""The cluster path of docs/REPRODUCE.md ("On a cluster"), run with submitit's local launcher:
Table 2's trainings as one ``gspi-train -m`` sweep through Hydra's submitit plugin, each job in
its own process and run folder; a rerun of the same sweep resumes (nothing left to train)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.stage2_fixtures import make_lattice_dataset

pytest.importorskip("hydra_plugins.hydra_submitit_launcher", reason="pip install -e .[dev] installs it")
BIN = Path(sys.executable).parent


def sweep(data: Path, runs: Path) -> subprocess.CompletedProcess:
    cmd = [str(BIN / "gspi-train"), "-m", f"data={data}", f"out={runs}/${{ablation_name}}_s${{seed}}", "stage2=tiny",
           "stage2.prior.alexnet.input_size=64", "stage2.train.steps=3", "ablation=full,a2_no_view_onehot", "seed=0",
           "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10", f"hydra.sweep.dir={runs}/.submitit"]
    return subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})


def test_trainings_run_as_submitit_jobs_in_their_own_folders(tmp_path):
    data = make_lattice_dataset(tmp_path / "data", num_train=2, num_test=1)
    proc = sweep(data, tmp_path / "runs")
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name, width in (("full_s0", 35), ("a2_no_view_onehot_s0", 3)):
        stats = json.loads((tmp_path / "runs" / name / "stats.json").read_text())
        assert stats["steps"] == 3, name
        assert (tmp_path / "runs" / name / "checkpoint.pt").is_file()
    assert list((tmp_path / "runs" / ".submitit").rglob("*_log.out"))  # submitit's own job logs
    again = sweep(data, tmp_path / "runs")  # a requeued job is the same call: it resumes at step 3
    assert again.returncode == 0, again.stderr[-3000:]
    assert json.loads((tmp_path / "runs" / "full_s0" / "stats.json").read_text())["steps"] == 3
