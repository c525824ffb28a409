"""A gspi-run job's Table 2 measure on the clouds it generated: ``<job>/points_eval/points_summary.json``
({"mean": {channel: {psnr, ssim, lpips}}, "per_scene": {scene: {channel: ...}}}), written by
gspi/run/runner.py and read by the sweep reader (eval/sweep.py). Named apart from gspi-eval's
``summary.json`` (eval.records.eval_folder), which it was called before session 12; jobs written
then are still read.
"""
from __future__ import annotations

from pathlib import Path

FOLDER = "points_eval"
NAME = "points_summary.json"
LEGACY_NAME = "summary.json"


def run_points_path(folder: str | Path) -> Path:
    """The summary in a job's ``points_eval`` folder: today's name, else the pre-session-12 one."""
    folder = Path(folder)
    return folder / LEGACY_NAME if not (folder / NAME).is_file() and (folder / LEGACY_NAME).is_file() else folder / NAME


def write_run_points(job: str | Path, summary: dict) -> Path:
    """``<job>/points_eval/points_summary.json``, atomically."""
    from eval.common.atomic import write_json_atomic

    return write_json_atomic(Path(job) / FOLDER / NAME, summary)
