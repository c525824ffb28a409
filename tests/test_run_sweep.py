"""Sweeps of gspi-run: a killed multirun loses nothing on rerun; wandb offline runs hold the config.

The micro dataset (tests/conftest.py) and the tiny stage settings (tests/run_helpers.py).
"""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.run_helpers import REPO, TINY_RUN, run_config

SWEEP = ["+experiment=table3", "figures=false", "eval.channels=[albedo,roughness,metallic]"]


def gspi_run(args: list[str], env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", **(env_extra or {})}
    return subprocess.run([sys.executable, "-m", "gspi.cli.run", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=1200)


def results(sweep: Path) -> dict[str, dict]:
    out = {}
    for path in sweep.rglob("result.json"):
        rec = json.loads(path.read_text())
        out[rec["ablation"]] = {**rec, "mtime": path.stat().st_mtime_ns}
    return out


def test_killed_multirun_is_completed_by_a_rerun_without_loss_or_duplicates(micro_dataset, tmp_path):
    sweep = tmp_path / "table3"
    args = ["-m", f"data={micro_dataset}", f"out={sweep}", *TINY_RUN, *SWEEP]
    killed = gspi_run(args, {"GSPI_KILL_AT": "a7_freeze_opacity:stage3"})
    assert killed.returncode != 0, killed.stderr[-2000:]
    before = results(sweep)
    # The sweep order is full, a6, a7, ...: two jobs finished, a7 died in Stage III, none after it.
    assert set(before) == {"full", "a6_no_distillation"}, before.keys()
    assert all(r["status"] == "complete" for r in before.values())

    rerun = gspi_run(args)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    after = results(sweep)
    assert set(after) == {"full", "a6_no_distillation", "a7_freeze_opacity", "a8_freeze_scaling", "a9_freeze_both"}
    assert all(r["status"] == "complete" for r in after.values())
    for name, rec in before.items():  # finished jobs were skipped, not redone
        assert after[name]["mtime"] == rec["mtime"]

    tables = tmp_path / "tables"
    table = subprocess.run([sys.executable, "-m", "eval.tables.cli", str(sweep), f"out={tables}"], cwd=REPO,
                           capture_output=True, text=True, timeout=600)
    assert table.returncode == 0, table.stderr[-3000:]
    with open(tables / "table3.csv") as f:
        rows = list(csv.DictReader(f))
    labels = [r[next(iter(r))] for r in rows]
    assert len(rows) == 5 and len(set(labels)) == 5, labels


def test_wandb_offline_run_holds_config_and_metrics(micro_dataset, tmp_path):
    pytest.importorskip("wandb")
    from gspi.run.runner import run_job

    # Two jobs in one process, as a multirun worker runs them: each run's log must be complete
    # when run_job returns (the tracker waits for wandb's service), and the second starts afresh.
    for job in ("a", "b"):
        out = tmp_path / job
        cfg = run_config(micro_dataset, out, ["method=no_decomposition", "logger=wandb", "figures=false",
                                              f"logger.run_name=job_{job}"])
        assert run_job(cfg)["status"] == "complete"
        runs = list((out / "wandb").glob("offline-run-*"))
        assert len(runs) == 1
        # Offline runs keep config, history and summary in the run's protobuf log (`wandb sync`
        # uploads it); its records hold the keys and values verbatim.
        (log_file,) = runs[0].glob("run-*.wandb")
        data = log_file.read_bytes()
        assert b"no_decomposition" in data and b"stage3" in data  # the resolved config
        assert f"job_{job}".encode() in data
        assert b"eval/albedo/psnr" in data and b"eval/relight/psnr" in data  # the metrics
