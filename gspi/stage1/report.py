"""What Stage I's steps do to the geometry: distances of points to a reference surface sample.

The reference is a scene's GT point cloud (``gt_points.npz`` ``xyz``: the unprojection of the GT
depth of the 32 lattice views, one point per foreground pixel). Distances are given in world
units and in *pixel footprints* (``z / f_x``: the world width of one lattice-render pixel at the
point's depth in its source view), so they read the same at any image size.

The reference is itself a sample of the surface, so a point exactly on the surface is still
some way from its nearest reference sample: ``reference_spacing`` (the reference's own
nearest-neighbour distances) is the floor of that measure.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.spatial import cKDTree


def source_footprint(xyz: np.ndarray, view: np.ndarray, K: np.ndarray, w2c: np.ndarray) -> np.ndarray:
    """[P] world width of one pixel at each point's depth in its source view.

    Args:
        xyz: [P, 3] world; view: [P] source view indices; K: [V, 3, 3]; w2c: [V, 4, 4].
    """
    z = np.einsum("pj,pj->p", w2c[view, 2, :3], xyz) + w2c[view, 2, 3]
    return z / K[view, 0, 0]


def distance_summary(dist: np.ndarray, footprint: np.ndarray, prefix: str = "") -> dict[str, float]:
    """mean / median / p95 of `dist` [P] in world units and in footprints (`footprint` [P])."""
    if len(dist) == 0:
        return {}
    px = dist / footprint
    return {f"{prefix}mean_dist": float(dist.mean()), f"{prefix}median_dist": float(np.median(dist)),
            f"{prefix}p95_dist": float(np.percentile(dist, 95)),
            f"{prefix}mean_px": float(px.mean()), f"{prefix}median_px": float(np.median(px)),
            f"{prefix}p95_px": float(np.percentile(px, 95))}


def step_stats(dist: Optional[np.ndarray], footprint: np.ndarray, *, removed: Optional[np.ndarray] = None) -> dict:
    """Count (and removed count) of one step; with distances to a reference, those of the kept
    points (``mean_dist`` ...) and of the points this step removed (``removed_mean_dist`` ...).

    Args:
        dist: [P] each point's distance to the reference surface sample (entering the step), or None;
        footprint: [P] their pixel footprints;
        removed: [P] bool, the points this step removed (None: the step removes nothing).
    """
    keep = np.ones(len(footprint), bool) if removed is None else ~removed
    stats = {"count": int(keep.sum())}
    if removed is not None:
        stats["removed"] = int(removed.sum())
    if dist is None or len(dist) == 0:
        return stats
    stats.update(distance_summary(dist[keep], footprint[keep]))
    if removed is not None:
        stats.update(distance_summary(dist[removed], footprint[removed], prefix="removed_"))
    return stats


def reference_spacing(reference: np.ndarray, footprint: np.ndarray) -> dict[str, float]:
    """The floor of the distance measure: each reference point's distance to its nearest OTHER
    reference point, summarised as in :func:`distance_summary` (`reference` [R, 3])."""
    dist, _ = cKDTree(reference).query(reference, k=2)
    return distance_summary(dist[:, 1], footprint)
