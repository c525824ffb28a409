"""An exclusive file lock, so parallel jobs of a sweep build a shared artefact once.

``fcntl.flock`` on ``<path>.lock``: POSIX only, released when the process dies, works across
the joblib workers of one machine and on shared filesystems that support flock (most NFS
setups do not: a SLURM sweep should build shared artefacts first, docs/REPRODUCE.md).
"""
from __future__ import annotations

import fcntl
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


@contextmanager
def file_lock(path: Path) -> Iterator[None]:
    """Holds an exclusive lock on ``<path>.lock`` for the duration of the block."""
    lock = Path(str(path) + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a+") as handle:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
