"""Objective of the joint inverse-rendering baseline: photometric term and material priors.

Photometric term (``gspi.recon.losses.photometric_loss``, Stage 0's): ``(1 - l) L1 + l (1 - SSIM)`` between the shaded render and the input
view, both through the display transform of Stage 0 (``gspi.recon.losses.display``: ACES
filmic + sRGB encoding of linear radiance). The inputs are HDR with a sun, so a loss on
linear radiance would be dominated by the few highlight pixels; the tone-mapped space
weighs shading and albedo errors as they are seen, and it is the space in which the
2DGS asset itself was fitted.

Priors, the GS-IR / R3DG kind the paper argues against:

* edge-aware ("bilateral") smoothness of the rendered albedo, roughness and metallic maps,
  ``mean |grad M| exp(-gamma |grad I|)`` over neighbouring foreground pixel pairs, with
  ``I`` the input image in display values (GS-IR's and R3DG's form);
* a metallic sparsity prior ``mean(metallic)`` (an L1 pull towards 0, dielectric unless the
  images demand metal);
* optionally nvdiffrec's white-light prior on the environment, ``mean |L - mean_c L|``.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["edge_aware_smoothness", "white_light_prior"]


def edge_aware_smoothness(maps: Tensor, valid: Tensor, guide: Tensor, gamma: float) -> Tensor:
    """Edge-aware total variation of material maps.

    Args:
        maps: [B, H, W, C] material values (any range).
        valid: [B, H, W] bool, pixels where the maps are defined (foreground).
        guide: [B, H, W, 3] guide image in [0, 1] (the input view, display values).
        gamma: Edge sharpness: a guide step of ``1 / gamma`` divides the weight by e.

    Returns:
        Scalar: mean over valid horizontal and vertical pixel pairs of
        ``mean_c |M_p - M_q| * exp(-gamma mean_c |I_p - I_q|)`` (0 when no pair is valid).
    """
    total, count = maps.new_zeros(()), 0
    for dim in (1, 2):  # rows, then columns
        n = maps.shape[dim] - 1
        d_map = (maps.narrow(dim, 1, n) - maps.narrow(dim, 0, n)).abs().mean(-1)
        d_guide = (guide.narrow(dim, 1, n) - guide.narrow(dim, 0, n)).abs().mean(-1)
        pair = valid.narrow(dim, 1, n) & valid.narrow(dim, 0, n)
        total = total + (d_map * torch.exp(-gamma * d_guide))[pair].sum()
        count += int(pair.sum())
    return total / max(count, 1)


def white_light_prior(envmap: Tensor) -> Tensor:
    """nvdiffrec's light regulariser ``mean |L - mean_c L|`` of a [h, w, 3] map."""
    return (envmap - envmap.mean(-1, keepdim=True)).abs().mean()
