"""What a set of views says about each point: one row per (point, view that sees it).

The record the light estimate and the material read-out share (``gspi.light``). Built from
renders, depths and cameras by ``gspi.stage2.light_views.observe_points`` (the asset's lattice
renders, the exact renders or the input photos); here only its shape and its checks.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor


@dataclass(frozen=True)
class PointViews:
    """Observations of ``num_points`` points.

    Attributes:
        point: [M] int64 index of the observed point (rows sorted by point, any order works).
        colour: [M, 3] float32 linear radiance the view saw at the point.
        view_dir: [M, 3] float32 unit vector from the point towards the view's camera.
        normal: [n, 3] float32 unit surface normal of each point.
        xyz: [n, 3] float32 point positions (for neighbourhood pooling).
    """

    point: Tensor
    colour: Tensor
    view_dir: Tensor
    normal: Tensor
    xyz: Tensor

    def __post_init__(self) -> None:
        m, n = len(self.point), len(self.normal)
        if self.colour.shape != (m, 3) or self.view_dir.shape != (m, 3):
            raise ValueError(f"colour {tuple(self.colour.shape)} and view_dir {tuple(self.view_dir.shape)} "
                             f"must be [{m}, 3] (one row per observation)")
        if self.normal.shape != (n, 3) or self.xyz.shape != (n, 3):
            raise ValueError(f"normal {tuple(self.normal.shape)} and xyz {tuple(self.xyz.shape)} must be [n, 3]")
        if m and (int(self.point.min()) < 0 or int(self.point.max()) >= n):
            raise ValueError(f"point indices must lie in [0, {n}), got [{int(self.point.min())}, "
                             f"{int(self.point.max())}]")
        if not bool(torch.isfinite(self.colour).all()):
            raise ValueError("colour holds NaN or inf: the views' radiance must be finite")

    @property
    def num_points(self) -> int:
        return len(self.normal)

    def views_per_point(self) -> Tensor:
        """[n] int64 how many views see each point."""
        return torch.bincount(self.point, minlength=self.num_points)

    def subset(self, keep: np.ndarray | Tensor) -> "PointViews":
        """The observations of points ``keep`` [k] (indices), renumbered 0..k-1 in that order."""
        keep = torch.as_tensor(np.asarray(keep), dtype=torch.int64)
        new_index = torch.full((self.num_points,), -1, dtype=torch.int64)
        new_index[keep] = torch.arange(len(keep))
        rows = new_index[self.point] >= 0
        return PointViews(point=new_index[self.point[rows]], colour=self.colour[rows],
                          view_dir=self.view_dir[rows], normal=self.normal[keep], xyz=self.xyz[keep])

    @classmethod
    def from_numpy(cls, point, colour, view_dir, normal, xyz) -> "PointViews":
        f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
        unit = lambda t: torch.nn.functional.normalize(t, dim=-1)  # noqa: E731
        return cls(point=torch.from_numpy(np.asarray(point, dtype=np.int64)), colour=f32(colour),
                   view_dir=unit(f32(view_dir)), normal=unit(f32(normal)), xyz=f32(xyz))
