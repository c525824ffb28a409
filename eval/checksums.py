"""SHA-256 checksums of what an evaluation scored: the predictions and the ground truth.

Recorded next to the protocol hash (eval_meta.json ``checksums``, gspi-run's result.json), so a
score names the exact bytes it is of (NerfBaselines records the same). A folder's checksum is the
SHA-256 of its sorted lines ``<relative path> <file SHA-256>``: renaming, adding, removing or
changing any file changes it; where the folder lives does not.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterable

ALGORITHM = "sha256 of the sorted lines '<path relative to the scene> <sha256 of the file>'"
CHUNK = 1 << 20


def file_sha256(path: Path) -> str:
    """SHA-256 hex digest of one file's bytes, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(CHUNK), b""):
            digest.update(block)
    return digest.hexdigest()


def files_sha256(root: Path, paths: Iterable[Path]) -> str:
    """The checksum of ``paths`` (files below ``root``) as this module defines it."""
    lines = sorted(f"{p.relative_to(root).as_posix()} {file_sha256(p)}" for p in paths)
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def tree_files(root: Path, parts: Iterable[str]) -> list[Path]:
    """Every file of ``root``/<part> for each part that exists (a file or a folder, recursively)."""
    found = []
    for part in parts:
        path = Path(root) / part
        if path.is_file():
            found.append(path)
        elif path.is_dir():
            found += [p for p in path.rglob("*") if p.is_file()]
    return found


def scene_checksums(gt_root: Path, pred_root: Path, split: str) -> dict:
    """{"ground_truth", "predictions"} of one scene: the GT's scene.json, environment maps and
    ``split`` views; the prediction's ``split`` views."""
    return {"ground_truth": files_sha256(gt_root, tree_files(gt_root, ("scene.json", "envmaps", split))),
            "predictions": files_sha256(pred_root, tree_files(pred_root, (split,)))}


def over_scenes(per_scene: dict[str, str]) -> str:
    """One checksum over every scene's: SHA-256 of the sorted '<scene> <checksum>' lines."""
    lines = sorted(f"{scene} {checksum}" for scene, checksum in per_scene.items())
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def combined(per_scene: dict[str, dict]) -> dict:
    """One checksum per side (ground truth, predictions) over every scene (``over_scenes``)."""
    return {side: over_scenes({scene: sums[side] for scene, sums in per_scene.items()})
            for side in ("ground_truth", "predictions")}
