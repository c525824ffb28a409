"""The 2DGS asset of each scene: given by the user, or reconstructed once and reused.

``assets=<file.ply>`` (one scene), ``assets=<dir>`` holding ``<dir>/<scene>/point_cloud.ply``
or ``<dir>/<scene>.ply`` (e.g. the output folders of gspi-recon or the official 2DGS code),
or ``assets=null``: Stage 0 (gspi/recon) fits the scene's ``train`` views, and the result is
cached at ``<cache>/recon/<hash of the recon config>/<scene>/point_cloud.ply`` so every job
of a sweep (every method, every ablation) starts from the SAME asset, as in the paper.
"""
from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any, Mapping, Optional

import torch

from eval.layout import Scene, write_json_atomic
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.ply import read_ply, write_ply
from gspi.run.locks import file_lock
from gspi.run.record import config_hash

log = logging.getLogger(__name__)


class AssetError(FileNotFoundError):
    """The asset a run was given cannot be found or read."""


def user_asset_path(assets: str | Path, scene_name: str, num_scenes: int) -> Path:
    """The PLY of ``scene_name`` under ``assets`` (a file for one scene, or a folder; a relative
    path that does not exist from the working directory is read from the repository root, so
    the shipped demo assets ``checkpoints/demo_assets`` work from anywhere)."""
    from gspi.run.stage2_model import resolve_path

    root = resolve_path(assets)
    if root.is_file():
        if num_scenes != 1:
            raise AssetError(f"{root}: one PLY given for {num_scenes} scenes; pass a folder with "
                             f"<scene>/point_cloud.ply, or select one scene with scenes=[name]")
        return root
    candidates = [root / scene_name / "point_cloud.ply", root / f"{scene_name}.ply"]
    for path in candidates:
        if path.is_file():
            return path
    raise AssetError(f"{root}: no 2DGS asset for scene {scene_name!r} (looked for "
                     f"{', '.join(str(c) for c in candidates)})")


def reconstruct(scene: Scene, recon_cfg: Mapping[str, Any], *, device: str = "cpu") -> tuple[Gaussians2D, dict]:
    """Stage 0 on the scene's ``train`` views (gspi/recon); returns the asset and its stats."""
    from gspi.recon.data import load_scene_views
    from gspi.recon.trainer import ReconConfig, fit_gaussians

    rcfg = ReconConfig.from_dict(dict(recon_cfg))
    views = load_scene_views(scene, "train").to(torch.device(device))
    result = fit_gaussians(views, rcfg)
    stats = {k: v for k, v in result.stats.items() if k != "history"}
    return result.gaussians.to("cpu"), stats


def cached_reconstruction(scene: Scene, recon_cfg: Mapping[str, Any], cache_root: Path, *,
                          device: str = "cpu") -> tuple[Gaussians2D, dict]:
    """Reconstructs once per (scene, recon config); parallel jobs wait on a file lock."""
    folder = Path(cache_root) / "recon" / config_hash(dict(recon_cfg), volatile=("log_every",)) / scene.name
    ply = folder / "point_cloud.ply"
    with file_lock(folder):
        if ply.is_file():
            info = json.loads((folder / "recon.json").read_text()) if (folder / "recon.json").is_file() else {}
            return read_ply(ply), {**info, "cached": True, "path": str(ply)}
        t0 = time.perf_counter()
        gaussians, stats = reconstruct(scene, recon_cfg, device=device)
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / "point_cloud.ply.tmp"
        write_ply(tmp, gaussians)
        info = {"scene": scene.name, "seconds": round(time.perf_counter() - t0, 2), "config": dict(recon_cfg),
                **{k: v for k, v in stats.items() if isinstance(v, (int, float, str))}}
        write_json_atomic(folder / "recon.json", info)
        os.replace(tmp, ply)
        return gaussians, {**info, "cached": False, "path": str(ply)}


def scene_asset(scene: Scene, *, assets: Optional[str], num_scenes: int, recon_cfg: Mapping[str, Any],
                cache_root: Path, device: str = "cpu") -> tuple[Gaussians2D, dict]:
    """(asset, info): info["source"] is "user" or "recon"; "seconds" is the reconstruction time
    (the cached run's time when reused, so end-to-end runtimes stay comparable)."""
    if assets:
        path = user_asset_path(assets, scene.name, num_scenes)
        try:
            gaussians = read_ply(path)
        except Exception as exc:
            raise AssetError(f"{path}: cannot read the 2DGS asset ({exc})") from exc
        return gaussians, {"source": "user", "path": str(path), "seconds": None}
    gaussians, info = cached_reconstruction(scene, recon_cfg, cache_root, device=device)
    return gaussians, {"source": "recon", **info}
