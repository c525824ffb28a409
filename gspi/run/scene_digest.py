"""What a scene is, by content: the digest of the files Stage II training reads (issue 54).

A trained Stage II model is cached under the hash of what made it (gspi/run/stage2_model.py).
Keying that by the dataset's absolute path made a moved or copied dataset a new dataset, and
retrained a model that takes hours at ``small`` scale. The digest here is the sha256 of a
scene's recipe (``scene.json``), its ground-truth point cloud (``gt_points.npz``) and every file
of its lattice views (``train/``), with their relative paths: the same data anywhere has the same
digest, and any changed pixel gives another.
"""
from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

TRAINING_FILES = ("scene.json", "gt_points.npz")  # beside the lattice folder
LATTICE_FOLDER = "train"  # the 32 lattice views (docs/FORMAT.md)
CHUNK = 1 << 20


def scene_files(scene_dir: Path) -> list[Path]:
    """The files of ``scene_dir`` that Stage II training reads, in a fixed order."""
    files = [scene_dir / name for name in TRAINING_FILES if (scene_dir / name).is_file()]
    lattice = scene_dir / LATTICE_FOLDER
    if lattice.is_dir():
        files += sorted(p for p in lattice.rglob("*") if p.is_file())
    return files


def scene_digest(scene_dir: str | Path) -> str:
    """sha256 hex digest of a scene's training files (relative path and bytes of each)."""
    scene_dir = Path(scene_dir)
    files = scene_files(scene_dir)
    stamp = tuple((str(p), p.stat().st_size, p.stat().st_mtime_ns) for p in files)
    return _digest(scene_dir, stamp)


@lru_cache(maxsize=4096)
def _digest(scene_dir: Path, stamp: tuple) -> str:
    """Memoised by every file's (path, size, mtime): a sweep's jobs hash a dataset once per process."""
    h = hashlib.sha256()
    for path, _, _ in stamp:
        path = Path(path)
        h.update(str(path.relative_to(scene_dir)).encode() + b"\0")
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(CHUNK), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()


def scenes_digest(data_dir: str | Path, names: list[str]) -> dict[str, str]:
    """``{scene name: scene_digest}`` for the named scenes of a dataset."""
    return {name: scene_digest(Path(data_dir) / name) for name in names}
