"""Un-premultiplying a method's maps by its own rendered opacity (`eval.unpremultiply`).

Splatting systems (IRGS, GS-IR) save each material map alpha-blended over a black background,
i.e. multiplied by the rendered opacity `a`; at silhouettes `a < 1` darkens the map. When a
prediction view carries that opacity (`alpha.png`, docs/FORMAT.md), `unpremultiply` divides
each map by it where the GT mask is set and `a > 0`, in the space the blending happened in:
albedo in linear RGB (sRGB-decoded, divided, clamped to [0, 1], re-encoded), roughness and
metallic as stored. Elsewhere (outside the mask, `a = 0`) values are left as they are.
"""
from __future__ import annotations

import torch
from torch import Tensor

from eval.common.colorspace import linear_to_srgb, srgb_to_linear


def unpremultiply(maps: dict[str, Tensor], alpha: Tensor, mask: Tensor) -> dict[str, Tensor]:
    """``maps`` ({channel: HxWxC}, albedo sRGB-encoded) divided by ``alpha`` (HxW or HxWx1)
    inside ``mask`` (HxW bool); returns new float64 tensors, the input is not changed."""
    a = alpha.reshape(mask.shape).double()
    where = (mask & (a > 0))[..., None]
    a = a.clamp_min(1e-12)[..., None]
    out = {}
    for channel, x in maps.items():
        x = x.double()
        if channel == "albedo":
            out[channel] = torch.where(where, linear_to_srgb((srgb_to_linear(x) / a).clamp(0.0, 1.0)), x)
        else:
            out[channel] = torch.where(where, (x / a).clamp(0.0, 1.0), x)
    return out
