"""On-disk cache of the global prior features, one file per scene and encoder configuration:

    <cache_dir>/<scene>/<encoder name>-<encoder hash>.pt
        {"features": [V, D, 5, 5] float32, "encoder": identity dict, "hash": str,
         "inputs": fingerprint of the scene's lattice rgb.exr files (name, size, mtime_ns)}
    <cache_dir>/<scene>/<encoder name>-<encoder hash>-map.pt
        the same with the unpooled [V, D, g, g] map (``stage2.data.pixel_features`` only)

A file is used only if it loads (``weights_only``), its hash, identity and input fingerprint
match and the tensor has the expected shape and finite values; anything else is recomputed
and rewritten (atomically), never trusted.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import torch
from torch import Tensor

from eval.common.atomic import atomic_path
from gspi.stage2.encoders import GRID_SIZE, PriorEncoder, encoder_hash, lattice_images_srgb

log = logging.getLogger(__name__)


def cache_path(cache_dir: str | Path, scene_name: str, encoder: PriorEncoder, *, unpooled: bool = False) -> Path:
    suffix = "-map" if unpooled else ""
    return Path(cache_dir) / scene_name / f"{encoder.name}-{encoder_hash(encoder)}{suffix}.pt"


def input_fingerprint(scene_dir: str | Path) -> list:
    """[(view id, size, mtime_ns)] of the lattice views' rgb.exr (changes when the data does)."""
    from eval.common.layout import read_scene

    scene = read_scene(scene_dir)
    out = []
    for view in scene.split_views("train"):
        stat = (scene.view_dir("train", view.id) / "rgb.exr").stat()
        out.append([view.id, int(stat.st_size), int(stat.st_mtime_ns)])
    return out


def _identity(encoder: PriorEncoder) -> dict:
    """The encoder identity as it reads back from disk (JSON types: lists, not tuples)."""
    return json.loads(json.dumps(encoder.identity(), sort_keys=True))


def _valid(entry: object, encoder: PriorEncoder, fingerprint: list, unpooled: bool) -> bool:
    if not isinstance(entry, dict) or not isinstance(entry.get("features"), Tensor):
        return False
    feats = entry["features"]
    shape_ok = (feats.dim() == 4 and tuple(feats.shape[:2]) == (len(fingerprint), encoder.feature_dim)
                and (min(feats.shape[2:]) > 0 if unpooled else tuple(feats.shape[2:]) == (GRID_SIZE, GRID_SIZE)))
    return (entry.get("hash") == encoder_hash(encoder) and entry.get("encoder") == _identity(encoder)
            and entry.get("inputs") == fingerprint and shape_ok
            and feats.dtype == torch.float32 and bool(torch.isfinite(feats).all()))


def load_cached(path: Path, encoder: PriorEncoder, fingerprint: list, *, unpooled: bool = False) -> Tensor | None:
    """Features from ``path`` if the file is present and valid, else None (with a log line)."""
    if not path.is_file():
        return None
    try:
        entry = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # any unreadable file is a miss: it is recomputed, not trusted
        log.warning("%s: unreadable feature cache (%s); recomputing", path, exc)
        return None
    if not _valid(entry, encoder, fingerprint, unpooled):
        log.warning("%s: stale or invalid feature cache; recomputing", path)
        return None
    return entry["features"]


def scene_prior_features(scene_dir: str | Path, encoder: PriorEncoder, cache_dir: str | Path | None
                         ) -> Tensor:
    """[V, D, 5, 5] global prior features of a scene's lattice views, cached per scene.

    Args:
        scene_dir: canonical scene folder (its ``train`` split = the 32 lattice views).
        encoder: a :class:`gspi.stage2.encoders.PriorEncoder`.
        cache_dir: cache root; None disables the cache.
    """
    scene_dir = Path(scene_dir)
    if encoder.feature_dim == 0:
        return encoder.encode(torch.zeros(len(input_fingerprint(scene_dir)), 3, 1, 1))
    return _cached_features(scene_dir, encoder, cache_dir, unpooled=False)


def scene_feature_maps(scene_dir: str | Path, encoder: PriorEncoder, cache_dir: str | Path | None) -> Tensor:
    """[V, D, g, g] unpooled encoder maps of a scene's lattice views (``stage2.data.pixel_features``),
    cached per scene beside the pooled grid."""
    return _cached_features(Path(scene_dir), encoder, cache_dir, unpooled=True)


def _cached_features(scene_dir: Path, encoder: PriorEncoder, cache_dir: str | Path | None, *,
                     unpooled: bool) -> Tensor:
    fingerprint = input_fingerprint(scene_dir)
    path = None if cache_dir is None else cache_path(cache_dir, scene_dir.name, encoder, unpooled=unpooled)
    if path is not None:
        cached = load_cached(path, encoder, fingerprint, unpooled=unpooled)
        if cached is not None:
            return cached
    images = lattice_images_srgb(scene_dir)
    feats = (encoder.encode_map(images) if unpooled else encoder.encode(images)).float().contiguous()
    if path is not None:
        with atomic_path(path) as tmp:
            torch.save({"features": feats, "encoder": _identity(encoder), "hash": encoder_hash(encoder),
                        "inputs": fingerprint}, tmp)
    return feats
