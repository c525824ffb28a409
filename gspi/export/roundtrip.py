"""The round trip of an exported GLB: its re-imported material maps against the PBR-GS renders.

``gspi-data import.glb=asset.glb`` renders the GLB's maps (ray-cast mesh, textures looked up at
the hit) at the views of a new scene, in the importer's unit frame (bounding-box centre at the
origin, farthest vertex at radius 1; ``scene.json`` -> ``generator.unit_frame``). The PBR-GS
asset is moved into that frame (centres ``(mu - c) s``, scales times s) and its maps rendered at
the same cameras by Stage III's renderer (``gspi.stage3.export.render_material_maps``: what
gspi-run writes as its predictions and gspi-eval scores). PSNR is the protocol's masked PSNR
(``eval.metrics.masked_psnr``: albedo sRGB-encoded, roughness and metallic linear, data range 1)
over the pixels both cover: the imported mask and the asset's alpha > 0.5; the two silhouettes'
IoU is reported beside it. Scores are means over views.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from eval.common.layout import MATERIAL_CHANNELS, read_scene, read_view_file
from eval.metrics import masked_psnr
from gspi.gaussians.model import Gaussians2D

ALPHA_COVERED = 0.5


def to_unit_frame(asset: Gaussians2D, center, scale: float) -> Gaussians2D:
    """The asset moved as the importer moves a mesh: ``x -> (x - center) * scale``."""
    from dataclasses import replace

    c = torch.as_tensor(np.asarray(center, dtype=np.float64), dtype=asset.means.dtype)
    return replace(asset, means=(asset.means - c) * scale, log_scales=asset.log_scales + math.log(scale))


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def compare_imported(asset: Gaussians2D, imported_scene: str | Path, *, split: str = "test",
                     backend: str = "auto") -> dict:
    """{"psnr": {channel: mean dB}, "mask_iou": mean, "views": n, "per_view": [...]} (module docstring)."""
    from gspi.stage3.export import render_material_maps

    scene = read_scene(imported_scene)
    frame = scene.extra.get("generator", {}).get("unit_frame")
    if frame is None:
        raise ValueError(f"{Path(imported_scene) / 'scene.json'}: no generator.unit_frame (not a gspi-data "
                         "import.glb scene)")
    views = scene.split_views(split)
    moved = to_unit_frame(asset.detach().to("cpu", torch.float32), frame["center"], float(frame["scale"]))
    maps = render_material_maps(moved, np.stack([v.K for v in views]), np.stack([v.w2c for v in views]),
                                scene.width, scene.height, backend=backend)
    per_view = []
    for i, view in enumerate(views):
        vdir = scene.view_dir(split, view.id)
        imported_mask = read_view_file(vdir, "mask.png")[..., 0] > 0.5
        covered = maps["alpha"][i, ..., 0] > ALPHA_COVERED
        both = imported_mask & covered
        row = {"view": view.id, "mask_iou": mask_iou(imported_mask, covered), "pixels": int(both.sum())}
        for channel in MATERIAL_CHANNELS:
            got = read_view_file(vdir, f"{channel}.png")
            row[channel] = masked_psnr(torch.from_numpy(got), torch.from_numpy(maps[channel][i]),
                                       torch.from_numpy(both)) if both.any() else float("nan")
        per_view.append(row)
    mean = lambda key: float(np.nanmean([r[key] for r in per_view]))  # noqa: E731
    return {"psnr": {c: mean(c) for c in MATERIAL_CHANNELS}, "mask_iou": mean("mask_iou"),
            "views": len(views), "split": split, "per_view": per_view}
