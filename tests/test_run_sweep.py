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


def _last_line(proc: subprocess.CompletedProcess) -> str:
    lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
    return lines[-1] if lines else ""


def test_sweep_tells_the_truth_about_failed_jobs(micro_dataset, tmp_path):
    """A sweep whose job fails exits non-zero naming it on its last line (it exited 0, each job
    logging "complete"); a whole sweep's last line says it is complete, with counts; gspi-table
    names the row whose job failed instead of printing one row fewer."""
    from eval.common.layout import read_scene, read_splits
    from tests.adapter_fixtures import gt_maps, write_gs_ir

    name = read_splits(micro_dataset)["test"][0]
    outputs = tmp_path / "gsir_outputs"
    write_gs_ir(outputs / name, gt_maps(read_scene(micro_dataset / name)), gamma=True)
    common = [f"data={micro_dataset}", f"++method.outputs={outputs}", "table=table1", "logger=none",
              "progress=false", "figures=false", "eval.channels=[albedo,roughness]"]

    good = gspi_run(["-m", f"out={tmp_path / 'good'}", "method=gs_ir", "seed=0,1", *common])
    assert good.returncode == 0, good.stderr[-3000:]
    assert _last_line(good).startswith("sweep complete: 2 job(s) complete in "), _last_line(good)
    again = gspi_run(["-m", f"out={tmp_path / 'good'}", "method=gs_ir", "seed=0,1", *common])
    assert again.returncode == 0 and "(2 skipped as already complete)" in _last_line(again), _last_line(again)

    sweep = tmp_path / "mixed"
    mixed = gspi_run(["-m", f"out={sweep}", "method=gs_ir,r3dg", *common])
    assert mixed.returncode == 1, mixed.stderr[-3000:]
    last = _last_line(mixed)
    assert last.startswith("run.py: error: sweep finished with 1 of 2 job(s) failed: "), last
    assert "method=r3dg" in last and "method=gs_ir" not in last, last
    assert "job ++method.outputs=" in mixed.stdout + mixed.stderr  # a job's own line names the job
    assert ",method=r3dg,table=table1: failed: " in mixed.stdout + mixed.stderr

    table = subprocess.run([sys.executable, "-m", "eval.tables.cli", str(sweep), f"out={tmp_path / 'tables'}"],
                           cwd=REPO, capture_output=True, text=True, timeout=600)
    assert table.returncode == 0, table.stderr[-3000:]
    warning = [line for line in table.stderr.splitlines() if "warning" in line]
    assert len(warning) == 1 and "table1: rows with failed or unfinished jobs: R3DG (method=r3dg" in warning[0]
    assert "1 failed job(s), missing from the table" in warning[0], warning
    assert "rows with failed or unfinished jobs: R3DG" in (tmp_path / "tables" / "table1.md").read_text()


def test_sweep_of_ablations_the_checkpoint_cannot_serve_is_refused_before_any_job(micro_dataset, tmp_path):
    """A2 with the shipped checkpoint failed inside its job, after Full had run; now one line
    before Hydra starts, naming the key to set, and no folder is made."""
    from gspi.cli.run import main
    from tests.reliability.helpers import run_cli

    out = tmp_path / "sweep"
    code, text = run_cli(main, ["-m", f"data={micro_dataset}", f"out={out}", "ablation=full,a2_no_view_onehot",
                                "logger=none"])
    lines = [line for line in text.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, text
    assert "ablation=a2_no_view_onehot" in lines[0] and "set stage2.checkpoint=null" in lines[0], lines[0]
    assert "stage2.data.local_condition" in lines[0] and not out.exists()
