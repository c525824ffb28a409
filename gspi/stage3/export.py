"""Exports of the PBR-GS asset: material maps at any cameras, predictions in the canonical layout.

The maps are those of ``render.render_materials`` (blend-weight average of the surfels on
each ray, albedo sRGB-encoded, 0 where the asset's alpha <= 1e-4). The PLY itself is written
by ``gspi.gaussians.ply.write_ply`` (material attributes documented there).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from eval.common.layout import Scene, write_material
from gspi.gaussians.model import Gaussians2D
from gspi.stage3.render import render_materials


@torch.no_grad()
def render_material_maps(asset: Gaussians2D, K, w2c, width: int, height: int, *, backend: str = "auto",
                         batch: int = 8) -> dict[str, np.ndarray]:
    """Material maps of a PBR asset at C cameras, as float32 numpy.

    Args:
        asset: surfels with PBR logits.
        K: [C, 3, 3] intrinsics (numpy or torch).
        w2c: [C, 4, 4] world-to-camera, OpenCV axes (numpy or torch).
        width: image width W.
        height: image height H.
        backend: rasterizer backend.
        batch: views per rasterizer call.

    Returns:
        {"albedo": [C, H, W, 3] sRGB-encoded, "roughness": [C, H, W, 1], "metallic": [C, H, W, 1],
        "alpha": [C, H, W, 1]}, all in [0, 1].
    """
    K = torch.as_tensor(np.asarray(K), dtype=asset.means.dtype, device=asset.device)
    w2c = torch.as_tensor(np.asarray(w2c), dtype=asset.means.dtype, device=asset.device)
    keys = ("albedo", "roughness", "metallic", "alpha")
    parts: dict[str, list] = {k: [] for k in keys}
    for start in range(0, len(K), batch):
        maps = render_materials(asset, w2c[start:start + batch], K[start:start + batch], width, height,
                                backend=backend)
        for k in keys:
            parts[k].append(maps[k].clamp(0.0, 1.0).float().cpu())
    return {k: torch.cat(v).numpy() for k, v in parts.items()}


def write_scene_predictions(asset: Gaussians2D, scene: Scene, out_scene_dir: Path, *, split: str = "test",
                            backend: str = "auto") -> list[Path]:
    """Renders the asset's material maps at a scene's views into the canonical prediction layout.

    Writes ``<out_scene_dir>/<split>/<view id>/{albedo,roughness,metallic}.png`` (16-bit, albedo
    sRGB-encoded) through ``eval.common.layout.write_material``; ``meta.json`` (method name, runtimes)
    is the runner's (``gspi.run``), not written here.

    Returns:
        The written paths, views in the scene's order.
    """
    views = scene.split_views(split)
    maps = render_material_maps(asset, np.stack([v.K for v in views]), np.stack([v.w2c for v in views]),
                                scene.width, scene.height, backend=backend)
    paths = []
    for i, view in enumerate(views):
        vdir = Path(out_scene_dir) / split / view.id
        paths += [write_material(vdir, channel, maps[channel][i]) for channel in ("albedo", "roughness", "metallic")]
    return paths
