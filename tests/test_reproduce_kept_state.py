"""Training state kept in the repository (gspi/reproduce/kept_state.py, issue 53): a begun run's
checkpoint copied out portable with its metrics up to the checkpoint's step, the copy of a measured
run removed, and a run with no checkpoint in its work folder started from its kept copy."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from gspi.cli import reproduce as cli
from gspi.reproduce.kept_state import keep, keep_state, restore
from gspi.stage2.checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, portable_config, save_atomic
from tests.machine_paths import MACHINE_PATH

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def reproduce(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "gspi-reproduce"), *args], cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"},
                          capture_output=True, text=True)


def begun_run(run_dir: Path, step: int, logged_to: int, *, best_step: int | None = None) -> None:
    """A run folder as gspi-train leaves it: a checkpoint at ``step`` whose config names this
    machine's folders, metrics logged past it (the chunk went on after its last checkpoint)."""
    best = {"step": best_step, "score": 1.0} if best_step is not None else {}
    save_atomic({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "rcw_config": {}, "ema": {},
                 "step": step, "best": best, "config": {"data": str(run_dir.parent / "rtrain"), "out": str(run_dir)}},
                run_dir / "checkpoint.pt")
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps({"step": s, "key": "loss", "value": 1.0 / s}) + "\n"
                                                   for s in range(1, logged_to + 1)))
    if best_step is not None:
        save_atomic({"best": {"step": best_step, "score": 1.0}}, run_dir / "best.pt")


def test_a_kept_copy_is_portable_and_stops_at_the_checkpoints_step(tmp_path):
    run = tmp_path / "work" / "runs_fast" / "full_s1"
    begun_run(run, step=250, logged_to=300, best_step=250)
    assert keep(run, tmp_path / "kept" / "full_s1") == 250
    kept = tmp_path / "kept" / "full_s1"
    steps = [json.loads(line)["step"] for line in (kept / "metrics.jsonl").read_text().splitlines()]
    assert steps == list(range(1, 251))  # the resume appends from step 251: no row twice
    config = torch.load(kept / "checkpoint.pt", weights_only=True)["config"]
    assert not MACHINE_PATH.search(json.dumps(config)) and config["out"].endswith("runs_fast/full_s1")
    original = torch.load(run / "checkpoint.pt", weights_only=True)["config"]
    assert config == portable_config(original)  # what gspi.stage2.checkpoint.make_portable writes
    assert (kept / "best.pt").is_file()
    assert str(tmp_path) in torch.load(run / "checkpoint.pt", weights_only=True)["config"]["out"]  # run untouched


def test_a_best_pt_of_a_later_validation_is_not_kept_with_an_earlier_checkpoint(tmp_path):
    run = tmp_path / "runs_fast" / "a2_s1"
    begun_run(run, step=250, logged_to=300, best_step=250)
    save_atomic({"best": {"step": 300, "score": 2.0}}, run / "best.pt")  # validated after the checkpoint
    keep(run, tmp_path / "kept" / "a2_s1")
    assert not (tmp_path / "kept" / "a2_s1" / "best.pt").exists()


def test_keep_state_keeps_begun_runs_and_removes_measured_ones(tmp_path):
    runs = tmp_path / "work" / "runs_fast"
    begun_run(runs / "a3_s2", step=500, logged_to=510)
    (runs / "a5_s2").mkdir(parents=True)  # begun, no checkpoint yet: nothing to keep
    stale = tmp_path / "kept" / "runs_fast" / "a2_s2"
    stale.mkdir(parents=True)
    (stale / "checkpoint.pt").write_bytes(b"x")
    lines = keep_state({n: runs / n for n in ("a2_s2", "a3_s2", "a5_s2")}, {"a2_s2"}, tmp_path / "kept")
    assert lines == [f"removed {stale}: its scores are committed",
                     f"kept a3_s2 at step 500 in {tmp_path / 'kept' / 'runs_fast' / 'a3_s2'}"]
    assert not stale.exists() and not (tmp_path / "kept" / "runs_fast" / "a5_s2").exists()
    restore(tmp_path / "kept" / "runs_fast" / "a3_s2", tmp_path / "fresh" / "a3_s2")
    assert torch.load(tmp_path / "fresh" / "a3_s2" / "checkpoint.pt", weights_only=True)["step"] == 500


def test_a_run_with_a_kept_copy_and_no_checkpoint_is_restored_before_it_trains(tmp_path, monkeypatch):
    monkeypatch.setattr(cli, "REPO", ROOT)
    kept = tmp_path / "kept"
    begun_run(kept / "runs_fast" / "a5_multiview_injection_s2", step=750, logged_to=750)
    args = [f"data_root={tmp_path}", "table=2", "scale=cpu", f"kept_state={kept}", f"scores_dir={tmp_path / 'none'}",
            "seeds=[2]", "variants=[a2_no_view_onehot,a5_multiview_injection]"]
    steps, _, _ = cli.plan(args)
    names = [s.name for s in steps if ": a" in s.name]
    assert names == ["train: a2_no_view_onehot_s2", "measure: a2_no_view_onehot_s2", "restore: a5_multiview_injection_s2",
                     "train: a5_multiview_injection_s2", "measure: a5_multiview_injection_s2"]
    restore_step = next(s for s in steps if s.name.startswith("restore"))
    assert restore_step.lane_group == "a5_multiview_injection_s2" and not restore_step.is_done()
    restore_step.action()
    assert restore_step.is_done()  # the checkpoint is in the work folder: a later call skips the step


def test_keep_state_without_a_folder_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "REPO", ROOT)
    assert cli.main([f"data_root={tmp_path}", "table=2", "scale=cpu", "kept_state=null", "keep_state=true"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "keep_state=true needs a kept_state folder" in err[0]


@pytest.mark.slow
def test_a_run_cut_kept_and_restored_on_an_empty_work_folder_gives_the_uninterrupted_scores(tmp_path):
    """Smoke Table 2: Full s0 cut at step 3 of 6, its state kept, its run folder deleted (another
    machine), the same command run again: the scores equal a straight run's."""

    keys = ["table=2", "scale=smoke", "variants=[full]", "seeds=[0]",
            "train_overrides=['stage2.train.steps=6','stage2.data.num_points=32']"]
    straight = reproduce(*keys, f"data_root={tmp_path / 'a'}")
    assert straight.returncode == 0, straight.stderr[-3000:]
    assert reproduce(*keys, f"data_root={tmp_path / 'b'}", "only=[data,stage]").returncode == 0
    work = tmp_path / "b" / "reproduce" / "table2_smoke"
    cut = subprocess.run([str(BIN / "gspi-train"), f"data={work / 'rtrain_tiny'}", f"out={work / 'runs_tiny' / 'full_s0'}",
                          "stage2=tiny", "ablation=full", "seed=0", "stage2.train.steps=6",
                          "stage2.data.num_points=32", "stage2.train.stop_at=3"], capture_output=True, text=True)
    assert cut.returncode == 0, cut.stderr[-3000:]
    kept = reproduce(*keys, f"data_root={tmp_path / 'b'}", "keep_state=true")
    assert kept.returncode == 0 and "kept full_s0 at step 3" in kept.stdout, kept.stdout + kept.stderr[-3000:]
    shutil.rmtree(work / "runs_tiny" / "full_s0")
    resumed = reproduce(*keys, f"data_root={tmp_path / 'b'}")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert json.loads((work / "runs_tiny" / "full_s0" / "stats.json").read_text())["resumed_from"] == 3
    assert "restore: full_s0" in resumed.stderr
    a, b = (json.loads((tmp_path / r / "reproduce" / "table2_smoke" / "scores" / "full_s0" / "scores.json").read_text())
            for r in ("a", "b"))
    assert a["per_scene"] == b["per_scene"]
