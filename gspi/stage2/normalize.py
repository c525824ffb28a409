"""Heterogeneous normalisation of Stage II's inputs and targets (paper Sec. "Geometry-
Conditioned, Feature-Only Diffusion": coordinates and bounded PBR features are normalised
separately before diffusion).

* Coordinates -> unit sphere. Centre = the axis-aligned BOUNDING-BOX centre (not the mean:
  Stage I point density follows view overlap, which would pull a mean towards densely seen
  parts), scale = the largest distance of a point from that centre, so every point lies in
  the unit ball and at least one on its surface. Fit it on the whole scene's cloud, then
  subsample: training subsets of 512 points must share the scene's frame.
* PBR features [albedo RGB, roughness, metallic] in [0, 1] -> [-1, 1] by ``v * 2 - 1``.
  Albedo is taken as stored by the dataset (``albedo.png``: sRGB-ENCODED in [0, 1],
  docs/FORMAT.md); roughness and metallic are linear. The inverse clamps to [0, 1].
"""
from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

PBR_CHANNELS = ("albedo_r", "albedo_g", "albedo_b", "roughness", "metallic")


class SphereFrame(NamedTuple):
    """Similarity that maps world coordinates to the unit sphere: ``(xyz - center) / scale``."""

    center: Tensor  # [..., 1, 3]
    scale: Tensor  # [..., 1, 1]


def fit_unit_sphere(xyz: Tensor, *, eps: float = 1e-12) -> SphereFrame:
    """Bounding-box centre and max radius of a point cloud.

    Args:
        xyz: [..., N, 3] world coordinates (N >= 1).
        eps: floor of the scale, so a single point does not divide by zero.
    Returns:
        SphereFrame with center [..., 1, 3] and scale [..., 1, 1].
    """
    if xyz.shape[-2] == 0:
        raise ValueError("cannot fit a unit sphere to an empty point cloud")
    center = 0.5 * (xyz.amin(dim=-2, keepdim=True) + xyz.amax(dim=-2, keepdim=True))
    radius = (xyz - center).norm(dim=-1, keepdim=True).amax(dim=-2, keepdim=True)
    return SphereFrame(center=center, scale=radius.clamp(min=eps))


def to_unit_sphere(xyz: Tensor, frame: SphereFrame) -> Tensor:
    """[..., N, 3] world -> [..., N, 3] unit-sphere coordinates."""
    return (xyz - frame.center) / frame.scale


def from_unit_sphere(xyz_unit: Tensor, frame: SphereFrame) -> Tensor:
    """[..., N, 3] unit-sphere -> [..., N, 3] world coordinates (inverse of to_unit_sphere)."""
    return xyz_unit * frame.scale + frame.center


def pbr_to_model(features: Tensor) -> Tensor:
    """[..., 5] PBR features in [0, 1] (albedo sRGB-encoded as stored, roughness, metallic)
    -> [..., 5] diffusion space [-1, 1] (``v * 2 - 1``)."""
    if features.shape[-1] != len(PBR_CHANNELS):
        raise ValueError(f"expected {len(PBR_CHANNELS)} PBR channels {PBR_CHANNELS}, got {features.shape[-1]}")
    return features * 2.0 - 1.0


def pbr_from_model(features_model: Tensor) -> Tensor:
    """[..., 5] diffusion-space features -> [..., 5] PBR values clamped to [0, 1]."""
    return ((features_model + 1.0) * 0.5).clamp(0.0, 1.0)


def view_onehot(view_index: Tensor, num_views: int = 32) -> Tensor:
    """[...] int lattice view indices -> [..., num_views] float32 one-hot (the 32-dim
    view-source indicator of paper Eq. per_point_cond)."""
    return torch.nn.functional.one_hot(view_index.long(), num_views).float()
