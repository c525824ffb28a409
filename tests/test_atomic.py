"""eval/common/atomic.py: a file written atomically gets the mode a plain ``open(path, "w")`` gives
under the current umask (0o666 & ~umask), not mkstemp's private 0600."""
from __future__ import annotations

import os
import stat
from contextlib import contextmanager

import pytest

from eval.common.atomic import atomic_path, current_umask, write_json_atomic, write_text_atomic


@contextmanager
def umask(mask: int):
    old = os.umask(mask)  # os.umask returns the previous mask: restored below
    try:
        yield
    finally:
        os.umask(old)


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def write_each(folder):
    """One file through each atomic writer, and one through plain open() for comparison."""
    write_text_atomic(folder / "a.txt", "x\n")
    write_json_atomic(folder / "b.json", {"k": 1})
    with atomic_path(folder / "c.bin") as tmp:
        tmp.write_bytes(b"\0")
    with open(folder / "plain.txt", "w") as f:
        f.write("x")
    return [folder / n for n in ("a.txt", "b.json", "c.bin")]


@pytest.mark.parametrize("mask, expected", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_atomic_files_honour_the_umask(tmp_path, mask, expected):
    with umask(mask):
        assert current_umask() == mask
        written = write_each(tmp_path)
    assert mode(tmp_path / "plain.txt") == expected
    for path in written:
        assert mode(path) == expected, path.name


def test_replacing_a_file_gives_the_umask_mode_again(tmp_path):
    with umask(0o077):
        write_text_atomic(tmp_path / "r.json", "1")
    with umask(0o022):
        write_text_atomic(tmp_path / "r.json", "2")
    assert mode(tmp_path / "r.json") == 0o644
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_current_umask_leaves_the_umask_unchanged():
    with umask(0o027):
        current_umask()
        assert os.umask(0o027) == 0o027
