"""Training state kept in the repository, so that a run begun on one machine resumes on another.

A Table 2 training (hours on a CPU) outlives a session, and the work folder (``data_root``) is not
committed. ``kept_state`` (conf/reproduce/table2_cpu.yaml: ``checkpoints/resume/table2_cpu``)
holds, for each run begun and not yet measured, what its resume reads:
``<kept>/<runs folder>/<run>/checkpoint.pt`` (model, EMA, optimizer, RNG states; its stored
config's paths made portable, which the resume does not read), ``metrics.jsonl`` up to the
checkpoint's step, and ``best.pt`` when it belongs to that checkpoint (a recipe that validates).

- ``gspi-reproduce table=2 scale=cpu keep_state=true`` writes these copies for the runs of the
  plan and removes the copy of every run whose scores are committed; then commit the folder.
- ``gspi-reproduce table=2 scale=cpu`` on a machine whose work folder lacks a run's checkpoint
  starts that run from its kept copy (a ``restore:`` step before its training), so a fresh clone
  goes on where the last machine stopped.
"""
from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

from gspi.repo import REPO  # stored paths become relative to it

log = logging.getLogger(__name__)
STATE_FILES = ("checkpoint.pt", "metrics.jsonl", "best.pt")


def restore(kept_run: Path, run_dir: Path) -> None:
    """Copies a kept run's state into its (empty) run folder; the training resumes from it."""
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in STATE_FILES:
        if (kept_run / name).is_file():
            shutil.copy2(kept_run / name, run_dir / name)
    log.info("restored %s from %s", run_dir.name, kept_run)


def keep(run_dir: Path, kept_run: Path) -> int | None:
    """Copies ``run_dir``'s training state to ``kept_run`` (portable checkpoint, metrics up to its
    step, its best.pt when it is that checkpoint's best); returns the step, None when the run has
    no checkpoint yet (nothing is written). Written beside ``kept_run`` and renamed into place."""
    import torch

    from eval.portable import portable

    ckpt = run_dir / "checkpoint.pt"
    if not ckpt.is_file():
        return None
    # one read: gspi-train replaces its checkpoint by a rename (save_atomic), never rewrites it in place
    saved = torch.load(ckpt, map_location="cpu", weights_only=True)
    tmp = kept_run.with_name(kept_run.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    # gspi.stage2.checkpoint.make_portable's rewrite; this floor runs the stages, never imports them
    # (tests/test_imports.py), so it applies eval.portable with the same root (the repository)
    torch.save({**saved, "config": portable(saved["config"], {"": REPO})}, tmp / "checkpoint.pt")
    step = int(saved["step"])
    if (run_dir / "metrics.jsonl").is_file():  # gspi.stage2.train_log's rows, as truncate_after keeps them
        rows = (run_dir / "metrics.jsonl").read_text().splitlines()
        (tmp / "metrics.jsonl").write_text("".join(line + "\n" for line in rows
                                                   if line.strip() and json.loads(line)["step"] <= step))
    best = run_dir / "best.pt"
    if best.is_file() and saved.get("best"):
        if torch.load(best, map_location="cpu", weights_only=True, mmap=True).get("best") == saved["best"]:
            shutil.copy2(best, tmp / "best.pt")
    shutil.rmtree(kept_run, ignore_errors=True)
    tmp.rename(kept_run)
    return step


def keep_state(run_dirs: dict[str, Path], measured: set[str], kept: Path) -> list[str]:
    """``keep`` for each planned run (name -> its run folder) not in ``measured``; the kept copy of
    every run in ``measured`` removed. Returns one line per change, for the caller to print."""
    lines = []
    for name, run_dir in sorted(run_dirs.items()):
        kept_run = kept / run_dir.parent.name / name
        if name in measured:
            if kept_run.exists():
                shutil.rmtree(kept_run)
                lines.append(f"removed {kept_run}: its scores are committed")
            continue
        step = keep(run_dir, kept_run)
        if step is not None:
            lines.append(f"kept {name} at step {step} in {kept_run}")
    return lines

