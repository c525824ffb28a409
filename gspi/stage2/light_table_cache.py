"""On-disk cache of a scene's light read-out table (``stage2.data.light_readout``), one file per
scene and key:

    <cache_dir>/<scene>/light-<key>.npz   {"xyz": [m, 3], "rows": [m, W], "info": the light told, JSON}

Reading a scene against its light (observing ~5 000 points in 32 views, the light estimate, the
grid fit) costs seconds a scene (7-8 s behind a pool scene's asset, beside two trainings); a
training resumed in chunks paid it again for every scene in every call (its first step 2.5 min
late on the 64-scene pool, 6-14 s with the tables kept), and every measure of the same held-out
scenes did too. The key hashes everything the table is a
function of: the whole ``stage2.data`` config, the light it is told (capture or estimated, and
how), the scene's name, the name, size and mtime of every file under the scene's folder and its
photos' folder, and the bytes of the gspi and eval sources that compute it. An edit to any of
them is a miss (the table is read again and written under its new key), never a stale table; an
unreadable or malformed file is a miss too, as in ``feature_cache``.
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path
from typing import Any, Optional

import numpy as np

from eval.common.atomic import atomic_path

log = logging.getLogger(__name__)


@lru_cache(maxsize=1)
def source_fingerprint() -> str:
    """sha256 of every .py file of the gspi and eval packages this process runs (name and bytes):
    the table's code. Any edit is a miss, so no rule has to list which modules the read-out calls."""
    from gspi.repo import REPO

    digest = hashlib.sha256()
    for package in (REPO / "gspi", REPO / "eval"):
        for path in sorted(package.rglob("*.py")):
            digest.update(str(path.relative_to(package.parent)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def folder_fingerprint(folder: Path) -> list:
    """[(relative path, size, mtime_ns)] of every file under ``folder``, hidden folders (caches) left out."""
    folder = Path(folder)
    out = []
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if path.is_file() and not any(part.startswith(".") for part in rel.parts):
            stat = path.stat()
            out.append([str(rel), int(stat.st_size), int(stat.st_mtime_ns)])
    return out


def table_key(cfg: Any, light_source: str, told_light: str, name: str, folders: list[Path]) -> str:
    """The cache key of a scene's table (module docstring): 24 hex digits."""
    inputs = {str(Path(f).resolve()): folder_fingerprint(f) for f in dict.fromkeys(folders)}
    record = {"data": asdict(cfg), "light_source": light_source, "told_light": told_light, "scene": name,
              "inputs": inputs, "code": source_fingerprint()}
    return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()[:24]


def table_path(cache_dir: Path, name: str, key: str) -> Path:
    return Path(cache_dir) / name / f"light-{key}.npz"


def load_table(path: Path) -> Optional[tuple[tuple[np.ndarray, np.ndarray], dict]]:
    """((xyz, rows), light info) from ``path``, or None where absent, unreadable or malformed."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as npz:
            xyz, rows, info = npz["xyz"], npz["rows"], json.loads(str(npz["info"]))
    except Exception as exc:  # any unreadable file is a miss: it is read again, not trusted
        log.warning("%s: unreadable light read-out cache (%s); reading the scene again", path, exc)
        return None
    if (xyz.ndim != 2 or xyz.shape[1] != 3 or rows.ndim != 2 or len(rows) != len(xyz)
            or not np.isfinite(xyz).all() or not isinstance(info, dict)):
        log.warning("%s: malformed light read-out cache; reading the scene again", path)
        return None
    return (xyz, rows), info


def save_table(path: Path, table: tuple[np.ndarray, np.ndarray], info: Optional[dict]) -> None:
    """Writes ``(xyz, rows)`` and the light info to ``path`` atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:  # a file object: np.savez would append .npz to a name
        np.savez(f, xyz=table[0], rows=table[1], info=np.array(json.dumps(info or {}, default=_plain)))


def _plain(value: Any) -> Any:
    """JSON for numpy scalars (np.bool_, np.float32) in the light info."""
    return value.item() if hasattr(value, "item") else str(value)
