"""What a 2DGS rasterizer returns: one record shared by every backend (torch, gsplat)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import torch.nn.functional as F
from torch import Tensor


@dataclass
class RenderOutput:
    """Rendered maps of C views (all [C, H, W, X], float).

    Attributes:
        rgb: [C, H, W, D] composited colours (from SH: linear RGB, D = 3) plus
            ``(1 - alpha) * backgrounds``; None when ``colors`` was None.
        features: [C, H, W, D] composited per-surfel features over a ZERO background
            (alpha-premultiplied); None when not requested.
        alpha: [C, H, W, 1] accumulated opacity ``1 - T_final``.
        depth_expected: [C, H, W, 1] ``sum_i w_i z_i / alpha``, 0 where alpha = 0.
        depth_median: [C, H, W, 1] depth of the surfel at which accumulated opacity
            crosses 0.5 (2DGS), 0 where no surfel is composited.
        normals: [C, H, W, 3] world-space, camera-facing surfel normals weighted by
            ``w_i`` and summed (not normalised; gsplat's ``render_normals``).
        depth_point: which point's depth was composited ("intersection" or "center").
        meta: per-surfel projection data: "radii" [C, N, 2] int32 (gsplat's, 0 = culled),
            "means2d" [C, N, 2], "depths" [C, N] centre depths.
    """

    rgb: Optional[Tensor]
    features: Optional[Tensor]
    alpha: Tensor
    depth_expected: Tensor
    depth_median: Tensor
    normals: Tensor
    depth_point: str = "intersection"
    meta: dict = field(default_factory=dict)

    @property
    def normals_unit(self) -> Tensor:
        """[C, H, W, 3] unit normals (the weighted sum normalised), 0 where alpha = 0."""
        return unit_normals(self.normals)


def unit_normals(normals: Tensor, eps: float = 1e-12) -> Tensor:
    """Normalises alpha-weighted normals [..., 3]; zero vectors stay zero."""
    return F.normalize(normals, dim=-1, eps=eps)
