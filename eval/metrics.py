"""Masked image metrics of the GS-PI protocol (docs/PROTOCOL.md), as small pure functions.

Inputs: `pred`, `gt` float tensors in [0, 1] of shape [H, W, C] (C = 1 or 3); `mask` [H, W]
(bool or 0/1) = the ground-truth foreground. Each function returns a Python float.

- PSNR: mean squared error over masked pixels (all channels) only (`region="mask"`), or over
  the whole image of both images multiplied by the mask (`region="image"`, Stanford-ORB's
  `divide_mask=False`). The MSE is floored at `mse_floor` (default: the error of 16-bit
  quantisation, (1/65535)^2 / 12, i.e. a cap of 107.1 dB), so PSNR is never +inf.
- SSIM: Gaussian window 11 (option), sigma 1.5, K1 = 0.01, K2 = 0.03, data range 1,
  population (co)variances, computed by `kornia.metrics.ssim`. `region="mask"`: both images
  composited on the same `background` outside the mask, the map evaluated where the window
  fits inside the image (`padding="valid"`, the border scikit-image crops) and averaged over
  the masked pixels there, then over channels; with an all-ones mask this is scikit-image's
  `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
  data_range=1)`. `region="image"`: the map of the composited images averaged over the
  whole image; with `padding="same"` and background 0 this is Stanford-ORB's
  `1 - 2 kornia.losses.ssim_loss(window 3)` on mask-multiplied images.
- LPIPS: LPIPS v0.1 (eval.lpips.net; AlexNet or VGG16, the network passed in) on inputs
  scaled to [-1, 1] (or fed as [0, 1] with `normalize=False`), grey maps replicated to 3
  channels, both images composited on `background`; mode "masked_mean" averages the
  spatial LPIPS map inside the mask, mode "composite" takes the ordinary full-image LPIPS of
  the composited pair.
- MAE and IoU (metallic): mean absolute error in the mask; IoU of thresholded maps.
"""
from __future__ import annotations

import math

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5  # kornia's fixed sigma for every window size
LPIPS_MODES = ("masked_mean", "composite")
REGIONS = ("mask", "image")
# 16-bit quantisation error: a uniform rounding error of step 1/65535 has variance step^2/12.
MSE_FLOOR_16BIT = (1.0 / 65535.0) ** 2 / 12.0
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


def _region(region: str) -> str:
    if region not in REGIONS:
        raise ValueError(f"unknown region {region!r}; allowed: {', '.join(REGIONS)}")
    return region


def squared_error_terms(pred: Tensor, gt: Tensor, mask: Tensor, *, region: str = "mask",
                        mask_pred: bool = True) -> tuple[Tensor, int]:
    """(sum of squared errors per channel [C], pixel count) of one image pair: over the masked
    pixels (`region="mask"`) or every pixel of the mask-multiplied images (`region="image"`;
    with ``mask_pred=False`` the prediction is not multiplied, so what it holds outside the
    mask counts, as GS-IR's evaluation does). Sums of several views give a pooled MSE."""
    pred, gt, mask = _check(pred, gt, mask)
    if _region(region) == "image":
        m = mask[..., None].to(pred)
        diff = (pred if not mask_pred else pred * m) - gt * m
        return (diff ** 2).sum(dim=(0, 1)), mask.numel()
    return ((pred - gt) ** 2)[mask].sum(dim=0), int(mask.sum())


def masked_mse(pred: Tensor, gt: Tensor, mask: Tensor, *, region: str = "mask",
               mask_pred: bool = True) -> float:
    """Mean squared error over the masked pixels and all channels (`region="mask"`), or over
    every pixel of the mask-multiplied images (`region="image"`; see `squared_error_terms`)."""
    sse, count = squared_error_terms(pred, gt, mask, region=region, mask_pred=mask_pred)
    return float(sse.sum() / (count * sse.numel()))


def psnr_from_mse(mse: float, *, mse_floor: float = MSE_FLOOR_16BIT,
                  data_range: float = 1.0) -> float:
    """10 log10(data_range^2 / max(mse, mse_floor)); finite for any mse_floor > 0."""
    if not mse_floor > 0:
        raise ValueError(f"mse_floor must be > 0 (PSNR is never +inf), got {mse_floor}")
    return 10.0 * math.log10(data_range**2 / max(mse, mse_floor))


def masked_psnr(pred: Tensor, gt: Tensor, mask: Tensor, *, data_range: float = 1.0,
                mse_floor: float = MSE_FLOOR_16BIT, region: str = "mask") -> float:
    """PSNR in dB from `masked_mse`; identical images score the cap 10 log10(1 / mse_floor)."""
    return psnr_from_mse(masked_mse(pred, gt, mask, region=region), mse_floor=mse_floor,
                         data_range=data_range)


def grey_psnr(gt: Tensor, mask: Tensor, *, region: str = "mask",
              mse_floor: float = MSE_FLOOR_16BIT) -> float:
    """PSNR of a constant 0.5 prediction: Stanford-ORB's lower bound ("grey floor")."""
    return masked_psnr(torch.full_like(torch.as_tensor(gt, dtype=torch.float64), 0.5), gt, mask,
                       region=region, mse_floor=mse_floor)


def erode_mask(mask: Tensor, radius_px: int) -> Tensor:
    """Binary erosion of an [H, W] mask by a (2 r + 1)^2 square; pixels beyond the image border
    do not erode, like cv2.erode's default border (and kornia.morphology.erosion, which gives the
    same result: tests/test_metrics.py). A square is a row segment then a column segment, so
    this is two 1-D max-pools of the complement (torch's max_pool2d pads with -inf: the border
    never erodes), O(r) per pixel where kornia's full (2r+1)^2 kernel is O(r^2); a radius beyond
    the image is the image's size (the window already covers it all)."""
    mask = torch.as_tensor(mask)
    if radius_px < 0:
        raise ValueError(f"mask erosion radius must be >= 0 px, got {radius_px}")
    keep = mask if mask.dtype == torch.bool else mask > 0.5
    if radius_px == 0:
        return keep
    r = min(int(radius_px), max(keep.shape))
    hole = (~keep).to(torch.float32)[None, None]
    hole = F.max_pool2d(hole, kernel_size=(1, 2 * r + 1), stride=1, padding=(0, r))
    hole = F.max_pool2d(hole, kernel_size=(2 * r + 1, 1), stride=1, padding=(r, 0))
    return hole[0, 0] < 0.5


SSIM_K1, SSIM_K2 = 0.01, 0.03  # scikit-image's (and kornia's) constants, data range 1
SSIM_PADDINGS = ("valid", "same", "zero")  # same = kornia (reflection), zero = 3DGS loss_utils


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> Tensor:
    """Normalised 1D Gaussian taps exp(-x^2 / (2 sigma^2)), x = -(size//2)..size//2."""
    x = torch.arange(size, dtype=torch.float64) - size // 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def ssim_map(pred: Tensor, gt: Tensor, *, window: int = SSIM_WINDOW, padding: str = "valid",
             eps: float = 0.0) -> Tensor:
    """SSIM map of [H, W, C] images, in the inputs' dtype and differentiable (Stage III's loss
    uses it): [H-w+1, W-w+1, C] for padding "valid", [H, W, C] for "same" and "zero".

    "same" (Stanford-ORB's call) is kornia.metrics.ssim with `eps` added to the denominator;
    kornia pads by *reflection*. "zero" pads with zeros (the 3DGS `loss_utils.ssim` that
    GS-IR and IRGS call: ``F.conv2d(..., padding=window // 2)``), written below because kornia
    offers no zero padding. "valid" with eps 0 (scikit-image's convention, our default and Stage III's loss) is the
    two separable convolutions below: in float64 kornia agrees with them to 1e-14 (tested), but
    in float32 it differs by ~2e-6, which would move Stage III's optimisation and every number
    of the demo; this form keeps them exactly as they were.
    """
    if padding == "same" or eps != 0.0:
        x, y = (t.permute(2, 0, 1)[None] for t in (pred, gt))
        return kornia.metrics.ssim(x, y, window, eps=eps, padding=padding)[0].permute(1, 2, 0)
    if padding not in ("valid", "zero"):
        raise ValueError(f"unknown SSIM padding {padding!r}; allowed: {', '.join(SSIM_PADDINGS)}")
    w = gaussian_window(window).to(pred)
    x = torch.stack([pred, gt, pred * pred, gt * gt, pred * gt]).permute(0, 3, 1, 2)  # [5,C,H,W]
    c, r = x.shape[1], (window // 2 if padding == "zero" else 0)
    x = x.reshape(1, 5 * c, *x.shape[2:])
    x = F.conv2d(x, w.view(1, 1, 1, -1).expand(5 * c, 1, 1, -1), groups=5 * c, padding=(0, r))
    x = F.conv2d(x, w.view(1, 1, -1, 1).expand(5 * c, 1, -1, 1), groups=5 * c, padding=(r, 0))
    mu_x, mu_y, xx, yy, xy = x.view(5, c, *x.shape[2:])
    var_x, var_y, cov = xx - mu_x**2, yy - mu_y**2, xy - mu_x * mu_y
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return s.permute(1, 2, 0)


def composite(image: Tensor, mask: Tensor, background: float) -> Tensor:
    """Replace pixels outside `mask` [H, W] by `background`."""
    return torch.where(mask[..., None], image, torch.full_like(image, background))


def masked_ssim(pred: Tensor, gt: Tensor, mask: Tensor, *, background: float = 0.0,
                window: int = SSIM_WINDOW, region: str = "mask", padding: str = "valid",
                mask_pred: bool = True) -> float:
    """Mean SSIM over masked pixels or the whole image (see the module docstring).

    Args:
        region: "mask" (map averaged over masked pixels) or "image" (over every pixel).
        padding: "valid" (map where the window fits: scikit-image, TensoIR), "same" (kornia's
            reflection padding: Stanford-ORB) or "zero" (the 3DGS `ssim` GS-IR and IRGS call).
        mask_pred: composite the prediction on `background` outside the mask too (False: it is
            scored as it is there, GS-IR's evaluation).
    """
    pred, gt, mask = _check(pred, gt, mask)
    h, w = mask.shape
    if window < 1 or window % 2 == 0:
        raise ValueError(f"SSIM window must be an odd number of pixels, got {window}")
    if min(h, w) < window:
        raise ValueError(f"image {h}x{w} is smaller than the SSIM window {window}")
    if padding not in SSIM_PADDINGS:
        raise ValueError(f"unknown SSIM padding {padding!r}; allowed: {', '.join(SSIM_PADDINGS)}")
    a = composite(pred, mask, background) if mask_pred else pred
    b = composite(gt, mask, background)
    if padding == "same":  # kornia's eps as Stanford-ORB's call (1e-5 in the background)
        s, inner = ssim_map(a, b, window=window, padding="same", eps=1e-12), mask
    elif padding == "zero":
        s, inner = ssim_map(a, b, window=window, padding="zero"), mask
    else:
        r = window // 2
        s, inner = ssim_map(a, b, window=window), mask[r:h - r, r:w - r]
    if _region(region) == "image":
        return float(s.mean())
    if not inner.any():
        raise ValueError(f"mask has no pixel at least {window // 2} pixels away from the "
                         "image border")
    return float(s[inner].mean())


def masked_mae(pred: Tensor, gt: Tensor, mask: Tensor) -> float:
    """Mean absolute error over the masked pixels and all channels."""
    pred, gt, mask = _check(pred, gt, mask)
    return float((pred - gt).abs()[mask].mean())


def masked_iou(pred: Tensor, gt: Tensor, mask: Tensor, *, threshold: float = 0.5) -> float:
    """IoU of {pred > threshold} and {gt > threshold} inside the mask (grey maps; 1 when both
    sets are empty)."""
    pred, gt, mask = _check(pred, gt, mask)
    p, g = (pred[..., 0] > threshold) & mask, (gt[..., 0] > threshold) & mask
    union = int((p | g).sum())
    return 1.0 if union == 0 else int((p & g).sum()) / union


def _to_lpips_input(image: Tensor, normalize: bool = True) -> Tensor:
    """[H, W, C] in [0, 1] -> [1, 3, H, W], grey replicated to 3 channels; mapped to [-1, 1]
    when `normalize` (PerceptualSimilarity's `normalize=True`), else fed as [0, 1] (the
    GS-IR/IRGS evaluation scripts do this; it lowers the distances)."""
    x = image.float().permute(2, 0, 1)[None]
    if x.shape[1] == 1:
        x = x.expand(-1, 3, -1, -1)
    return x * 2.0 - 1.0 if normalize else x


def masked_lpips(pred: Tensor, gt: Tensor, mask: Tensor, *, net=None, mode: str = "masked_mean",
                 background: float = 0.0, normalize: bool = True, mask_pred: bool = True) -> float:
    """LPIPS v0.1 (the network `net` was built with) restricted to the mask (module docstring).

    Args:
        net: an `eval.lpips.net.LPIPS`; AlexNet from the local weight cache when None.
        mode: "masked_mean" (spatial map averaged in the mask) or "composite" (full image).
        normalize: map inputs from [0, 1] to [-1, 1] first (the reference usage).
        mask_pred: composite the prediction on `background` too (False: GS-IR's evaluation).
    """
    if mode not in LPIPS_MODES:
        raise ValueError(f"unknown LPIPS mode {mode!r}; allowed: {', '.join(LPIPS_MODES)}")
    pred, gt, mask = _check(pred, gt, mask)
    if min(mask.shape) < LPIPS_MIN_SIZE:
        raise ValueError(f"image {tuple(mask.shape)} too small for LPIPS "
                         f"(needs >= {LPIPS_MIN_SIZE} px per side)")
    if net is None:
        from eval.lpips.net import load_lpips
        net = load_lpips()
    device = next(net.parameters()).device
    x = _to_lpips_input(composite(pred, mask, background) if mask_pred else pred, normalize).to(device)
    y = _to_lpips_input(composite(gt, mask, background), normalize).to(device)
    with torch.no_grad():
        if mode == "composite":
            return float(net(x, y).reshape(()))
        dist = net(x, y, spatial=True)[0, 0].cpu().double()  # [H, W]
    return float(dist[mask.cpu()].mean())
