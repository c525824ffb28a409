"""Colour-space conversions and display tone mapping (pure tensor functions).

All functions take and return float tensors of any shape; no clamping unless stated.
"""
from __future__ import annotations

import torch
from torch import Tensor

TONEMAPS = ("clamp", "aces", "reinhard")


def srgb_to_linear(x: Tensor, *, clamp: bool = True) -> Tensor:
    """IEC 61966-2-1 sRGB decoding of values in [0, 1] (input clamped first); with
    ``clamp=False`` the curve continues past 1 (an aligned albedo relit unclamped)."""
    if clamp:
        x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: Tensor, *, clamp: bool = True) -> Tensor:
    """IEC 61966-2-1 sRGB encoding; input clamped to [0, 1] first. With ``clamp=False`` the
    curve continues past 1 (the inverse of ``srgb_to_linear(..., clamp=False)``: an aligned
    albedo kept unclamped, as GS-IR and IRGS keep it)."""
    x = x.clamp(0.0, 1.0) if clamp else x.clamp_min(0.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(1e-12) ** (1.0 / 2.4) - 0.055)


def aces_filmic(x: Tensor) -> Tensor:
    """Narkowicz's ACES filmic fit (the curve GS-IR uses), clamped to [0, 1]."""
    x = x.clamp_min(0.0)
    return ((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)).clamp(0.0, 1.0)


def tonemap(radiance_linear: Tensor, *, mode: str = "aces", exposure_stops: float = 0.0,
            srgb: bool = True) -> Tensor:
    """Linear HDR radiance -> display values in [0, 1].

    Args:
        radiance_linear: linear radiance, any shape.
        mode: "clamp" (clip to [0, 1]), "aces" (Narkowicz ACES fit) or "reinhard" (x / (1 + x)).
        exposure_stops: multiply by 2**exposure_stops before the curve.
        srgb: apply the sRGB encoding after the curve.
    """
    if mode not in TONEMAPS:
        raise ValueError(f"unknown tone map {mode!r}; allowed: {', '.join(TONEMAPS)}")
    x = radiance_linear * (2.0 ** exposure_stops)
    if mode == "clamp":
        x = x.clamp(0.0, 1.0)
    elif mode == "aces":
        x = aces_filmic(x)
    else:
        x = x.clamp_min(0.0)
        x = x / (1.0 + x)
    return linear_to_srgb(x) if srgb else x
