"""Per-view geometry shared by the evaluator and the benchmark generator.

`view_directions` gives, per pixel, the unit vector from the surface toward the camera, which
is all split-sum shading needs (the environment is at infinity). `relight_view` is THE path
that turns per-view material maps into a relit image: ground truth and predictions both go
through it, so a perfect prediction reproduces the ground truth bit for bit.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from eval.common.colorspace import srgb_to_linear


def pixel_rays(K: np.ndarray, w2c: np.ndarray, height: int, width: int, *,
               dtype: torch.dtype = torch.float32) -> Tensor:
    """World-space unit ray directions through pixel centres (j + 0.5, i + 0.5).

    Args:
        K: [3, 3] pixel intrinsics. w2c: [4, 4] world-to-camera, OpenCV axes.
        dtype: of the result (computed in float64).
    Returns:
        [H, W, 3] unit directions, camera -> scene.
    """
    K = torch.as_tensor(K, dtype=torch.float64)
    w2c = torch.as_tensor(w2c, dtype=torch.float64)
    j, i = torch.meshgrid(torch.arange(width, dtype=torch.float64) + 0.5,
                          torch.arange(height, dtype=torch.float64) + 0.5, indexing="xy")
    pix = torch.stack([j, i, torch.ones_like(j)], dim=-1)           # [H, W, 3]
    dirs_cam = pix @ torch.linalg.inv(K).T                           # [H, W, 3]
    dirs_world = dirs_cam @ w2c[:3, :3]                              # R^T d, row-vector form
    return torch.nn.functional.normalize(dirs_world, dim=-1).to(dtype)


def view_directions(K: np.ndarray, w2c: np.ndarray, height: int, width: int) -> Tensor:
    """[H, W, 3] unit vectors from the surface toward the camera (= -pixel ray)."""
    return -pixel_rays(K, w2c, height, width)


def relight_view(albedo_srgb: Tensor | None, roughness: Tensor, metallic: Tensor, normal: Tensor,
                 view_dir: Tensor, env, *, albedo_linear: Tensor | None = None) -> Tensor:
    """Shade one view's material maps under an environment with the split-sum shader.

    Args:
        albedo_srgb: [H, W, 3] sRGB-encoded albedo in [0, 1] (as stored in albedo.png).
        albedo_linear: [H, W, 3] linear albedo used instead (may exceed 1: an aligned albedo
            relit unclamped, ``eval.relight.clamp_albedo: false``).
        roughness, metallic: [H, W, 1] linear in [0, 1].
        normal: [H, W, 3] world-space normals (normalised here; zero normals give black).
        view_dir: [H, W, 3] unit vectors surface -> camera.
        env: lat-long HDR map [h, w, 3] or a prefiltered environment (eval.relight).
    Returns:
        [H, W, 3] linear radiance; pixels with a zero normal are 0.
    """
    from eval.relight import split_sum  # local import: keeps this module light to import

    valid = normal.norm(dim=-1, keepdim=True) > 0.5
    n = torch.nn.functional.normalize(normal, dim=-1)
    n = torch.where(valid, n, view_dir)  # any unit vector; masked out below
    base = srgb_to_linear(albedo_srgb) if albedo_linear is None else albedo_linear
    radiance = split_sum(base, roughness, metallic, n, view_dir, env)
    return torch.where(valid, radiance, torch.zeros_like(radiance))
