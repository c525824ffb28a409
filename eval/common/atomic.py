"""The one atomic writer: a file is replaced whole or not at all.

    with atomic_path(out / "checkpoint.pt") as tmp:
        torch.save(state, tmp)
    write_json_atomic(out / "result.json", record)

Every result, record, cache and checkpoint of the project is written through :func:`atomic_path`
(a unique temporary file in the target's folder, then ``os.replace``), so a killed writer leaves
the old file or none, never half a file, and two writers of one path cannot collide on the
temporary name. The final file gets the mode a plain ``open(path, "w")`` would give it
(``0o666 & ~umask``), not ``mkstemp``'s private 0600. Lives in ``eval/`` because the evaluator
imports nothing from ``gspi/``.
"""
from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator


def current_umask() -> int:
    """The process's umask, read without changing it where the OS allows (Linux's
    ``/proc/self/status``); elsewhere ``os.umask`` is set and restored at once."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def created_file_mode() -> int:
    """The permission bits ``open(path, "w")`` gives a new file: ``0o666 & ~umask``."""
    return 0o666 & ~current_umask()


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yields a temporary path beside ``path``; renamed onto ``path`` when the block succeeds,
    removed when it raises (or the process is interrupted)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, created_file_mode())  # mkstemp made it 0600; a plain open() honours umask
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Writes ``text`` to ``path`` atomically; returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_json_atomic(path: str | Path, data: Any, *, allow_nan: bool = False) -> Path:
    """Writes ``data`` as indented JSON atomically. ``allow_nan=False`` (the default) refuses
    NaN and infinities; summaries that store PSNR = inf pass ``allow_nan=True`` (JSON's
    ``Infinity`` extension, which Python's json reads back)."""
    return write_text_atomic(path, json.dumps(data, indent=2, allow_nan=allow_nan) + "\n")
