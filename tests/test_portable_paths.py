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
