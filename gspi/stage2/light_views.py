"""The lattice views as observations of each point, for the light estimate and the material
read-out (``gspi.light``): every view that sees a point (``project_to_views``' depth test, the
one the cross-view statistic uses) gives the radiance at its pixel and the direction to its camera.
"""
from __future__ import annotations

import numpy as np

from gspi.light.observations import PointViews
from gspi.stage2.lattice_cameras import LatticeCameras, project_to_views


def observe_points(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray,
                   normal: np.ndarray, *, tol_pixels: float = 2.0, chunk: int = 8192) -> PointViews:
    """PointViews of points ``xyz`` [n, 3] with unit ``normal`` [n, 3] in the linear renders
    ``images`` [V, H, W, 3] with depths ``depth`` [V, H, W] of cameras ``cams``."""
    if images.shape[:3] != depth.shape or images.shape[-1] != 3:
        raise ValueError(f"images {images.shape} must be [V, H, W, 3] over depth {depth.shape} [V, H, W]")
    centers = cams.centers
    points, colours, dirs = [], [], []
    for s in range(0, len(xyz), chunk):
        part = xyz[s:s + chunk]
        row, col, _, visible = project_to_views(cams, depth, part, tol_pixels=tol_pixels)
        view, local = np.nonzero(visible)  # [V, n] -> (view, point) pairs
        order = np.lexsort((view, local))      # rows sorted by point, then view
        view, local = view[order], local[order]
        points.append(local + s)
        colours.append(images[view, row[view, local], col[view, local]])
        dirs.append(centers[view] - part[local])
    return PointViews.from_numpy(np.concatenate(points), np.concatenate(colours), np.concatenate(dirs),
                                 normal, xyz)
