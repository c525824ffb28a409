"""Differentiable material maps of a PBR 2DGS asset (paper: A^_v, R^_v, M^_v).

Colour space: ``Gaussians2D.albedo`` is LINEAR RGB. The rasterizer composites the linear
albedo, roughness and metallic of the surfels alpha-premultiplied over zero; a map is that
sum divided by the accumulated alpha where alpha > ``min_alpha`` (0 elsewhere), i.e. the
blend-weight average of the surfels on the ray. The albedo map is then sRGB-encoded
(``eval.common.colorspace.linear_to_srgb``), so the Stage III loss compares it with the sRGB targets
and the exported maps are in the canonical layout's encoding (albedo PSNR during distillation
and in ``gspi-eval`` measure the same thing).
"""
from __future__ import annotations

import torch
from torch import Tensor

from eval.common.colorspace import linear_to_srgb
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import rasterize_2dgs

MATERIALS = ("albedo", "roughness", "metallic")


def render_materials(asset: Gaussians2D, viewmats: Tensor, Ks: Tensor, width: int, height: int, *,
                     backend: str = "auto", min_alpha: float = 1e-4) -> dict[str, Tensor]:
    """Renders the material maps of C views (differentiable w.r.t. PBR logits, opacities, scales).

    Args:
        asset: surfels with PBR logits (``asset.has_pbr``).
        viewmats: [C, 4, 4] world-to-camera (OpenCV).
        Ks: [C, 3, 3] intrinsics.
        width: image width W.
        height: image height H.
        backend: rasterizer backend ("auto", "torch", "numba", "gsplat").
        min_alpha: pixels with accumulated alpha <= this get 0 in every map.

    Returns:
        {"albedo": [C, H, W, 3] sRGB-encoded, "roughness": [C, H, W, 1], "metallic": [C, H, W, 1],
        "alpha": [C, H, W, 1], "depth_median": [C, H, W, 1] camera z (0 where empty)}.
    """
    out = rasterize_2dgs(asset.means, asset.quats, asset.scales, asset.opacities, None, viewmats, Ks,
                         width, height, features=asset.pbr_features(), backend=backend)
    alpha = out.alpha
    covered = alpha > min_alpha
    maps = torch.where(covered, out.features / torch.where(covered, alpha, torch.ones_like(alpha)), 0.0)
    return {"albedo": torch.where(covered, linear_to_srgb(maps[..., :3]), 0.0),
            "roughness": maps[..., 3:4], "metallic": maps[..., 4:5],
            "alpha": alpha, "depth_median": out.depth_median}


@torch.no_grad()
def render_geometry(asset: Gaussians2D, viewmats: Tensor, Ks: Tensor, width: int, height: int, *,
                    backend: str = "auto", batch: int = 8) -> tuple[Tensor, Tensor]:
    """Alpha and median depth of the input asset (no gradients), views in batches.

    Returns:
        (alpha [C, H, W], depth_median [C, H, W] camera z, 0 where no surfel is composited).
    """
    alphas, depths = [], []
    for start in range(0, len(viewmats), batch):
        out = rasterize_2dgs(asset.means, asset.quats, asset.scales, asset.opacities, None,
                             viewmats[start:start + batch], Ks[start:start + batch], width, height,
                             backend=backend)
        alphas.append(out.alpha[..., 0])
        depths.append(out.depth_median[..., 0])
    return torch.cat(alphas), torch.cat(depths)


@torch.no_grad()
def render_base_color(asset: Gaussians2D, viewmats: Tensor, Ks: Tensor, width: int, height: int, *,
                      backend: str = "auto", batch: int = 8, min_alpha: float = 1e-4) -> Tensor:
    """[C, H, W, 3] LINEAR blend-weight average of the surfels' SH degree-0 base colour
    (``Gaussians2D.base_color``, clamped to [0, 1]); 0 where alpha <= ``min_alpha``."""
    base = asset.base_color().clamp(0.0, 1.0)
    maps = []
    for start in range(0, len(viewmats), batch):
        out = rasterize_2dgs(asset.means, asset.quats, asset.scales, asset.opacities, None,
                             viewmats[start:start + batch], Ks[start:start + batch], width, height,
                             features=base, backend=backend)
        covered = out.alpha > min_alpha
        maps.append(torch.where(covered, out.features / torch.where(covered, out.alpha, torch.ones_like(out.alpha)), 0.0))
    return torch.cat(maps)
