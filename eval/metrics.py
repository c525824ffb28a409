"""Masked image metrics of the GS-PI protocol (docs/PROTOCOL.md), as small pure functions.

Inputs: `pred`, `gt` float tensors in [0, 1] of shape [H, W, C] (C = 1 or 3); `mask` [H, W]
(bool or 0/1) = the ground-truth foreground. Each function returns a Python float.

- PSNR: mean squared error over masked pixels (all channels) only.
- SSIM: Gaussian window 11, sigma 1.5, K1 = 0.01, K2 = 0.03, data range 1, population
  (co)variances: scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=1)`. Both images are first composited on the same
  `background` outside the mask (so pixels outside the mask cannot change the score); the
  SSIM map is evaluated where the window fits inside the image (scikit-image crops the same
  5-pixel border) and averaged over the masked pixels there, then over channels. With an
  all-ones mask this is exactly scikit-image's mean SSIM.
- LPIPS: AlexNet LPIPS v0.1 (eval.lpips_net) on inputs scaled to [-1, 1], grey maps
  replicated to 3 channels, both images composited on `background`; mode "masked_mean"
  averages the spatial LPIPS map inside the mask, mode "composite" takes the ordinary
  full-image LPIPS of the composited pair.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03
LPIPS_MODES = ("masked_mean", "composite")
LPIPS_MIN_SIZE = 32  # AlexNet's five stages need at least this many pixels per side


def _check(pred: Tensor, gt: Tensor, mask: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Validate shapes and values; return float64 pred, gt [H, W, C] and bool mask [H, W]."""
    pred, gt, mask = torch.as_tensor(pred), torch.as_tensor(gt), torch.as_tensor(mask)
    if pred.ndim == 2:
        pred = pred[..., None]
    if gt.ndim == 2:
        gt = gt[..., None]
    if pred.ndim != 3 or pred.shape[-1] not in (1, 3):
        raise ValueError(f"pred must be HxWxC with C in (1, 3), got shape {tuple(pred.shape)}")
    if pred.shape != gt.shape:
        raise ValueError(f"pred shape {tuple(pred.shape)} != gt shape {tuple(gt.shape)}")
    if mask.ndim == 3 and mask.shape[-1] == 1:
        mask = mask[..., 0]
    if tuple(mask.shape) != tuple(gt.shape[:2]):
        raise ValueError(f"mask shape {tuple(mask.shape)} != image size {tuple(gt.shape[:2])}")
    for name, t in (("pred", pred), ("gt", gt)):
        if not torch.isfinite(t).all():
            raise ValueError(f"{name} contains {int((~torch.isfinite(t)).sum())} NaN/Inf values")
    mask = mask.bool() if mask.dtype == torch.bool else mask > 0.5
    if not mask.any():
        raise ValueError("mask is empty: no foreground pixel to evaluate")
    return pred.double(), gt.double(), mask


def masked_mse(pred: Tensor, gt: Tensor, mask: Tensor) -> float:
    """Mean squared error over the masked pixels and all channels."""
    pred, gt, mask = _check(pred, gt, mask)
    return float(((pred - gt) ** 2)[mask].mean())


def masked_psnr(pred: Tensor, gt: Tensor, mask: Tensor, *, data_range: float = 1.0) -> float:
    """PSNR in dB from the MSE over masked pixels; `inf` for identical images."""
    mse = masked_mse(pred, gt, mask)
    return math.inf if mse == 0.0 else 10.0 * math.log10(data_range**2 / mse)


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """Normalised 1D Gaussian taps exp(-x^2 / (2 sigma^2)), x = -(size//2)..size//2."""
    x = torch.arange(size, dtype=torch.float64) - size // 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def ssim_map(pred: Tensor, gt: Tensor) -> Tensor:
    """SSIM map of [H, W, C] float64 images where the window fits: [H-10, W-10, C].

    Why not kornia.metrics.ssim: it pads the border and keeps float32, so it cannot match
    scikit-image to 1e-4 on small images; this valid-window form does, with 2 separable convs.
    """
    w = gaussian_window().to(pred)
    x = torch.stack([pred, gt, pred * pred, gt * gt, pred * gt]).permute(0, 3, 1, 2)  # [5,C,H,W]
    c = x.shape[1]
    x = x.reshape(1, 5 * c, *x.shape[2:])
    x = F.conv2d(x, w.view(1, 1, 1, -1).expand(5 * c, 1, 1, -1), groups=5 * c)
    x = F.conv2d(x, w.view(1, 1, -1, 1).expand(5 * c, 1, -1, 1), groups=5 * c)
    mu_x, mu_y, xx, yy, xy = x.view(5, c, *x.shape[2:])
    var_x, var_y, cov = xx - mu_x**2, yy - mu_y**2, xy - mu_x * mu_y
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return s.permute(1, 2, 0)


def composite(image: Tensor, mask: Tensor, background: float) -> Tensor:
    """Replace pixels outside `mask` [H, W] by `background`."""
    return torch.where(mask[..., None], image, torch.full_like(image, background))


def masked_ssim(pred: Tensor, gt: Tensor, mask: Tensor, *, background: float = 0.0) -> float:
    """Mean SSIM over masked pixels (see the module docstring for the exact convention)."""
    pred, gt, mask = _check(pred, gt, mask)
    h, w = mask.shape
    if min(h, w) < SSIM_WINDOW:
        raise ValueError(f"image {h}x{w} is smaller than the SSIM window {SSIM_WINDOW}")
    s = ssim_map(composite(pred, mask, background), composite(gt, mask, background))
    r = SSIM_WINDOW // 2
    inner = mask[r:h - r, r:w - r]
    if not inner.any():
        raise ValueError("mask has no pixel at least 5 pixels away from the image border")
    return float(s[inner].mean())


def _to_lpips_input(image: Tensor) -> Tensor:
    """[H, W, C] in [0, 1] -> [1, 3, H, W] in [-1, 1], grey replicated to 3 channels."""
    x = image.float().permute(2, 0, 1)[None]
    if x.shape[1] == 1:
        x = x.expand(-1, 3, -1, -1)
    return x * 2.0 - 1.0


def masked_lpips(pred: Tensor, gt: Tensor, mask: Tensor, *, net=None, mode: str = "masked_mean",
                 background: float = 0.0) -> float:
    """AlexNet LPIPS v0.1 restricted to the mask (see the module docstring).

    Args:
        net: an `eval.lpips_net.LPIPS`; loaded from the local weight cache when None.
        mode: "masked_mean" (spatial map averaged in the mask) or "composite" (full image).
    """
    if mode not in LPIPS_MODES:
        raise ValueError(f"unknown LPIPS mode {mode!r}; allowed: {', '.join(LPIPS_MODES)}")
    pred, gt, mask = _check(pred, gt, mask)
    if min(mask.shape) < LPIPS_MIN_SIZE:
        raise ValueError(f"image {tuple(mask.shape)} too small for AlexNet LPIPS "
                         f"(needs >= {LPIPS_MIN_SIZE} px per side)")
    if net is None:
        from eval.lpips_net import load_lpips
        net = load_lpips()
    device = next(net.parameters()).device
    x = _to_lpips_input(composite(pred, mask, background)).to(device)
    y = _to_lpips_input(composite(gt, mask, background)).to(device)
    with torch.no_grad():
        if mode == "composite":
            return float(net(x, y).reshape(()))
        dist = net(x, y, spatial=True)[0, 0].cpu().double()  # [H, W]
    return float(dist[mask].mean())
