"""No tracked text file names an absolute path of one machine (issue 53): a checkout, a data
folder or a run folder is named relative to the repository (``data/...``) or by a placeholder
(``<checkout>``, ``<work>``), so the docs, configs and committed scores read the same anywhere."""
import subprocess
from pathlib import Path

import pytest

from tests.machine_paths import MACHINE_PATH

ROOT = Path(__file__).resolve().parents[1]
BINARY = {".pt", ".png", ".ply", ".npz", ".glb", ".exr", ".jpg", ".bin", ".whl"}


def tracked_text_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [ROOT / p for p in out.splitlines() if Path(p).suffix not in BINARY and (ROOT / p).is_file()]


def test_no_tracked_file_names_a_machine_path():
    found = []
    for path in tracked_text_files():
        if path.name in (Path(__file__).name, "machine_paths.py"):
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        found += [f"{path.relative_to(ROOT)}:{n}" for n, line in enumerate(text.splitlines(), 1)
                  if MACHINE_PATH.search(line)]
    assert not found, f"absolute machine paths in tracked files: {found[:10]}"


def test_the_pattern_catches_what_it_should():
    assert MACHINE_PATH.search("WORK=/root/data/x") and MACHINE_PATH.search("`/Users/u/data`")
    assert MACHINE_PATH.search("WORK=${WORK:-/root/data/x}")  # a shell default
    assert not MACHINE_PATH.search("runs/method=gspi/work/s002/pbr_gs.ply") and not MACHINE_PATH.search("out=/tmp/t3")


def test_the_committed_training_log_names_runs_without_a_machine_path(tmp_path):
    """gspi-train appends to docs/log/stage2_runs.jsonl (committed): a run under the repository by
    its relative path, a run elsewhere (here a temporary folder) without its machine root."""
    import json

    from gspi.stage2.train import append_run_log

    stats = {"seed": 0, "resumed_from": 0, "steps": 10, "total_steps": 10, "wall_time_s": 1.0, "final_loss": 0.5}
    log = tmp_path / "runs.jsonl"
    append_run_log(log, tmp_path / "elsewhere" / "full_s0", stats, cpu_s=1.0, commit=None)
    append_run_log(log, ROOT / "data" / "runs" / "full_s1", stats, cpu_s=1.0, commit=None)
    lines = [json.loads(line) for line in log.read_text().splitlines()]
    assert [line["out"] for line in lines] == ["<elsewhere>/elsewhere/full_s0", "data/runs/full_s1"]
    assert not MACHINE_PATH.search(log.read_text())
