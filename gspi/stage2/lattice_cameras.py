"""The 32 lattice cameras of a scene and where a point falls in each (Stage II's conditions).

``LatticeCameras`` (intrinsics, world -> camera), a pixel's world width at a depth, and
``project_to_views``: a point's pixel in every view and whether the view sees it (A5's depth test),
which A5's multi-view condition, ``pixel_feature_spread`` and the cross-view radiance statistic
(``gspi.stage2.view_statistics``) share.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class LatticeCameras:
    """The scene's 32 lattice cameras (its ``train`` split, in lattice order)."""

    K: np.ndarray  # [V, 3, 3] float64 pixel intrinsics
    w2c: np.ndarray  # [V, 4, 4] float64 OpenCV world -> camera
    width: int
    height: int

    @classmethod
    def from_renders(cls, renders) -> "LatticeCameras":
        """The cameras of Stage I's lattice renders (``gspi.gaussians.lattice_render.LatticeRenders``)."""
        height, width = renders.rgb.shape[1:3]
        return cls(K=np.asarray(renders.K, np.float64), w2c=np.asarray(renders.w2c, np.float64),
                   width=width, height=height)

    @property
    def centers(self) -> np.ndarray:  # [V, 3] world camera centres
        R, t = self.w2c[:, :3, :3], self.w2c[:, :3, 3]
        return -np.einsum("vji,vj->vi", R, t)

    def project(self, xyz: np.ndarray, views: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points [..., 3] in cameras ``views`` [...] -> pixel (u, v) [..., 2] and depth z [...]."""
        R, t = self.w2c[views, :3, :3], self.w2c[views, :3, 3]
        cam = np.einsum("...ij,...j->...i", R, xyz) + t
        z = cam[..., 2]
        K = self.K[views]
        u = K[..., 0, 0] * cam[..., 0] / z + K[..., 0, 2]
        v = K[..., 1, 1] * cam[..., 1] / z + K[..., 1, 2]
        return np.stack([u, v], axis=-1), z


def pixel_footprint(z: np.ndarray, cameras: LatticeCameras, views: np.ndarray) -> np.ndarray:
    """[...] world width of one pixel at camera depth z of views ``views`` (``z / f_x``)."""
    return z / cameras.K[views, 0, 0]


def project_to_views(cams: LatticeCameras, depth: np.ndarray, xyz: np.ndarray, *, tol_pixels: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points xyz [n, 3] in every view of ``cams`` with depth maps ``depth`` [V, H, W]: (row, col)
    [V, n] of the nearest pixel (0 outside the image), ``inside`` [V, n] (in front, in the image)
    and ``visible`` [V, n] (inside, depth > 0, ``|z - depth| < tol_pixels * z / f_x``)."""
    num_views = len(depth)
    views = np.broadcast_to(np.arange(num_views)[:, None], (num_views, len(xyz)))
    uv, z = cams.project(xyz[None], views)
    col, row = np.floor(uv[..., 0]).astype(np.int64), np.floor(uv[..., 1]).astype(np.int64)
    inside = (z > 0) & (col >= 0) & (col < cams.width) & (row >= 0) & (row < cams.height)
    col, row = np.where(inside, col, 0), np.where(inside, row, 0)
    d_map = depth[views, row, col]
    visible = inside & (d_map > 0) & (np.abs(d_map - z) < tol_pixels * pixel_footprint(z, cams, views))
    return row, col, inside, visible
