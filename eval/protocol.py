"""Protocol steps between reading files and computing metrics: albedo alignment, tone mapping.

Pure functions on tensors; `eval/evaluate.py` applies them in the order docs/PROTOCOL.md gives.
"""
from __future__ import annotations

import torch
from torch import Tensor

from eval.common.colorspace import linear_to_srgb, srgb_to_linear, tonemap


ALIGNMENT_ALIASES = {"per_channel": "lstsq"}  # the spelling of protocol v1 docs, kept
MEDIAN_EPS = 1e-6  # TensoIR's clamp of the prediction before the ratio


def _decoder(space: str):
    if space == "linear":
        return lambda x: srgb_to_linear(x.double())
    if space == "stored":
        return lambda x: x.double()
    raise ValueError(f"unknown alignment space {space!r}; allowed: linear, stored")


def fit_albedo_scale(pred_srgb: list[Tensor], gt_srgb: list[Tensor], masks: list[Tensor],
                     mode: str, space: str = "linear") -> Tensor:
    """Scale of the predicted albedo towards the ground truth over masked pixels, in LINEAR
    RGB (``space="linear"``) or on the stored values (``"stored"``: TensoIR, GS-IR and IRGS
    read their albedo PNGs as linear and fit on what the file holds).

    Args:
        pred_srgb, gt_srgb: lists of [H, W, 3] sRGB-encoded albedos (pooled together).
        masks: matching [H, W] bool masks.
        mode: "none" -> ones; "scale" -> one least-squares scale for all channels;
            "lstsq" (alias "per_channel") -> one least-squares scale per channel,
            argmin |s pred - gt|^2 (NeRFactor, Stanford-ORB); "median_ratio" -> per channel the
            median of gt / max(pred, 1e-6) (TensoIR `compute_rescale_ratio`, GS-IR, IRGS mode 2;
            torch.median: the lower middle value for an even count, as in TensoIR).
    Returns:
        [3] scale (in ``space``), on the masks' device.
    """
    mode = ALIGNMENT_ALIASES.get(mode, mode)
    ones = dict(dtype=torch.float64, device=masks[0].device if masks else None)
    if mode == "none":
        return torch.ones(3, **ones)
    decode = _decoder(space)
    p = torch.cat([decode(x)[m] for x, m in zip(pred_srgb, masks)])  # [P, 3]
    g = torch.cat([decode(x)[m] for x, m in zip(gt_srgb, masks)])
    if p.shape[0] == 0:
        return torch.ones(3, **ones)
    if mode == "scale":
        den = (p * p).sum()
        s = (p * g).sum() / den if den > 0 else torch.tensor(1.0, **ones)
        return s.expand(3).clone()
    if mode == "lstsq":
        den = (p * p).sum(0)
        return torch.where(den > 0, (p * g).sum(0) / den.clamp_min(1e-30), torch.ones(3, **ones))
    if mode == "median_ratio":
        return (g / p.clamp_min(MEDIAN_EPS)).median(dim=0).values
    raise ValueError(f"unknown albedo alignment {mode!r}; allowed: none, scale, lstsq, "
                     "per_channel (= lstsq), median_ratio")


def apply_albedo_scale(albedo_srgb: Tensor, scale: Tensor, space: str = "linear", clamp: bool = True
                       ) -> Tensor:
    """Scale an sRGB-encoded albedo in linear space (re-encoded after) or on its stored values
    (``space="stored"``), clamped to [0, 1] unless ``clamp`` is False (GS-IR and IRGS keep the
    scaled values; TensoIR relights with them)."""
    if torch.all(scale == 1):
        return albedo_srgb
    if space == "stored":
        out = albedo_srgb.double() * scale.to(torch.float64)
        return (out.clamp(0.0, 1.0) if clamp else out).to(albedo_srgb.dtype)
    lin = _decoder(space)(albedo_srgb) * scale.to(torch.float64)
    return linear_to_srgb(lin, clamp=clamp).to(albedo_srgb.dtype)


def unclamped_linear_albedo(albedo_srgb: Tensor, scale: Tensor, space: str = "linear") -> Tensor:
    """The linear albedo after the alignment scale, not clamped above 1 (TensoIR relights with
    ``albedo * ratio`` as it is)."""
    if space == "stored":
        return srgb_to_linear((albedo_srgb.double() * scale.to(torch.float64)).clamp_min(0.0), clamp=False)
    return _decoder(space)(albedo_srgb) * scale.to(torch.float64)


def display_relit(radiance_linear: Tensor, relight_cfg) -> Tensor:
    """Linear relit radiance -> the values scored: display values in [0, 1], or for tone map
    "none" linear radiance clipped to [0, relight.hdr_max] (no sRGB)."""
    if relight_cfg.tonemap == "none":
        return (radiance_linear * 2.0 ** float(relight_cfg.exposure_stops)).clamp(
            0.0, float(relight_cfg.hdr_max))
    return tonemap(radiance_linear, mode=relight_cfg.tonemap,
                   exposure_stops=float(relight_cfg.exposure_stops), srgb=bool(relight_cfg.srgb))
