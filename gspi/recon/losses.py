"""Photometric losses of the reconstruction (3DGS recipe) and 2DGS's normal consistency.

The display transform maps linear HDR radiance to the values the loss and the held-out
metrics compare: ``eval.common.colorspace.tonemap`` (default ACES filmic + sRGB encoding, the
evaluation protocol's relighting display transform). Both the rendered and the input
radiance go through it; the asset itself stays in linear radiance (SH colours are
unbounded above, so highlights brighter than 1 are representable).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from eval.common.colorspace import tonemap
from gspi.gaussians.cameras import unproject

SSIM_C1, SSIM_C2 = 0.01**2, 0.03**2


def display(radiance: Tensor, *, mode: str = "aces", exposure_stops: float = 0.0, srgb: bool = True) -> Tensor:
    """Linear radiance -> display values in [0, 1] (``eval.common.colorspace.tonemap``)."""
    return tonemap(radiance, mode=mode, exposure_stops=exposure_stops, srgb=srgb)


def _gauss_window(size: int = 11, sigma: float = 1.5, *, dtype=torch.float32, device=None) -> Tensor:
    x = torch.arange(size, dtype=dtype, device=device) - size // 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def ssim(x: Tensor, y: Tensor, window: int = 11) -> Tensor:
    """Mean SSIM of [B, H, W, C] images in [0, 1], differentiable.

    The 3DGS training SSIM (``utils/loss_utils.py``): Gaussian window 11, sigma 1.5, zero
    padding so every pixel has a value (the reported metric is ``eval.metrics.masked_ssim``).
    """
    b, h, w, c = x.shape
    g = _gauss_window(window, dtype=x.dtype, device=x.device)
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=-1).permute(0, 3, 1, 2)  # [B, 5C, H, W]
    k = stack.shape[1]
    pad = window // 2
    stack = F.conv2d(stack, g.view(1, 1, 1, -1).expand(k, 1, 1, -1), padding=(0, pad), groups=k)
    stack = F.conv2d(stack, g.view(1, 1, -1, 1).expand(k, 1, -1, 1), padding=(pad, 0), groups=k)
    mu_x, mu_y, xx, yy, xy = stack.split(c, dim=1)
    var_x, var_y, cov = xx - mu_x**2, yy - mu_y**2, xy - mu_x * mu_y
    s = ((2 * mu_x * mu_y + SSIM_C1) * (2 * cov + SSIM_C2)) / ((mu_x**2 + mu_y**2 + SSIM_C1) * (var_x + var_y + SSIM_C2))
    return s.mean()


def photometric_loss(pred: Tensor, gt: Tensor, lambda_dssim: float = 0.2) -> tuple[Tensor, dict]:
    """``(1 - lambda) L1 + lambda (1 - SSIM)`` on [B, H, W, 3] display values (3DGS, lambda 0.2)."""
    l1 = (pred - gt).abs().mean()
    if lambda_dssim > 0:
        dssim = 1.0 - ssim(pred, gt)
    else:
        dssim = torch.zeros((), dtype=pred.dtype, device=pred.device)
    loss = (1.0 - lambda_dssim) * l1 + lambda_dssim * dssim
    return loss, {"l1": float(l1.detach()), "dssim": float(dssim.detach())}


def depth_normals(depth: Tensor, K: Tensor, w2c: Tensor) -> Tensor:
    """World normals from a z-depth map by central differences (2DGS ``depth_to_normal``).

    Args:
        depth: [C, H, W, 1] camera z.
        K: [C, 3, 3]; w2c: [C, 4, 4].

    Returns:
        [C, H, W, 3] unit normals facing the camera, zero on the one-pixel border.
    """
    pts = unproject(depth, K, w2c)  # [C, H, W, 3]
    d_row = pts[:, 2:, 1:-1] - pts[:, :-2, 1:-1]
    d_col = pts[:, 1:-1, 2:] - pts[:, 1:-1, :-2]
    n = F.normalize(torch.linalg.cross(d_row, d_col, dim=-1), dim=-1)
    return F.pad(n, (0, 0, 1, 1, 1, 1))


def normal_consistency(render, K: Tensor, w2c: Tensor) -> Tensor:
    """2DGS normal-consistency loss ``mean(1 - n_render . (n_depth * alpha))``.

    ``n_render`` is the alpha-weighted rendered surfel normal, ``n_depth`` the normal of the
    rendered expected depth (2DGS's default ``depth_ratio = 0``), weighted by the detached alpha.
    """
    n_depth = depth_normals(render.depth_expected, K, w2c) * render.alpha.detach()
    return (1.0 - (render.normals * n_depth).sum(-1)).mean()
