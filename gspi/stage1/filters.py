"""The three geometric filters of Stage I (paper, Experiments, "Geometric filtering").

Each returns a boolean keep-mask over the points; all are pure functions of the point cloud and
the lattice renders, so their effect can be measured one by one (`gspi.stage1.extract`).

(i)   statistical outlier removal: mean distance to the k nearest neighbours (scipy's cKDTree)
      above mean + std_ratio * std of that statistic -> removed (Open3D's definition);
(ii)  cross-view foreground-mask consistency: a surface point must project into the
      foreground of every other view that sees it in frame; landing on background (alpha <
      threshold, after a 1-pixel dilation for silhouette quantisation) in more than
      `max_violations` views -> removed;
(iii) depth consensus across neighbouring views: in the `num_neighbours` lattice views closest
      in direction to the source view, a point lying clearly IN FRONT of the rendered median
      depth (by more than `tolerance_px` pixel footprints; the nearest foreground depth within
      `window_px` pixels, so a depth edge is not read as empty space) occupies space those views
      see as empty: more than `max_violations` such views -> removed. Points behind the rendered depth
      are occluded there and count neither way. Points are removed, never moved: moving them
      would break the hard binding between a point and the pixel its RGB came from.
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree


def statistical_outliers_keep(xyz: np.ndarray, *, k: int = 16, std_ratio: float = 2.0
                              ) -> np.ndarray:
    """Keep-mask of filter (i) for `xyz` [P, 3]."""
    if len(xyz) <= k:
        return np.ones(len(xyz), dtype=bool)
    dist, _ = cKDTree(xyz).query(xyz, k=k + 1)  # first neighbour is the point itself
    mean_dist = dist[:, 1:].mean(axis=1)
    return mean_dist <= mean_dist.mean() + std_ratio * mean_dist.std()


def project(xyz: np.ndarray, K: np.ndarray, w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (row, col as floats, pixel centres at +0.5) and camera z, per view.

    Args:
        xyz: [P, 3]; K: [V, 3, 3]; w2c: [V, 4, 4].
    Returns:
        rc [V, P, 2] (row, col) and z [V, P].
    """
    # batched matmul (BLAS) rather than np.einsum, which does not use it here: 3x faster, the same
    # products summed in another order (the Stage I clouds of the demo assets are identical)
    cam = np.matmul(xyz, w2c[:, :3, :3].transpose(0, 2, 1)) + w2c[:, None, :3, 3]
    z = cam[..., 2]
    uvw = np.matmul(cam, K.transpose(0, 2, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        col, row = uvw[..., 0] / z, uvw[..., 1] / z
    return np.stack([row, col], axis=-1), z


def _lookup(images: np.ndarray, rc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-pixel values of `images` [V, H, W] at `rc` [V, P, 2]; and an in-frame mask."""
    v, h, w = images.shape
    i, j = np.floor(rc[..., 0]).astype(np.int64), np.floor(rc[..., 1]).astype(np.int64)
    inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
    i, j = np.clip(i, 0, h - 1), np.clip(j, 0, w - 1)
    return images[np.arange(v)[:, None], i, j], inside


def mask_consistency_keep(xyz: np.ndarray, source_view: np.ndarray, alpha: np.ndarray,
                          K: np.ndarray, w2c: np.ndarray, *, alpha_threshold: float = 0.5,
                          max_violations: int = 1, dilate_px: int = 1) -> np.ndarray:
    """Keep-mask of filter (ii). alpha: [V, H, W] rendered opacity of the lattice views."""
    fg = torch.from_numpy(alpha >= alpha_threshold).float()[:, None]
    if dilate_px > 0:
        fg = torch.nn.functional.max_pool2d(fg, 2 * dilate_px + 1, stride=1, padding=dilate_px)
    fg = fg[:, 0].numpy() > 0.5
    violations = np.zeros(len(xyz), np.int32)
    # one view at a time: the [V, P] arrays of all views at once (~190 MB at 240k points)
    # made the filter memory-bound and ~5x slower; each view's values are the same bits
    for v in range(len(w2c)):
        rc, z = project(xyz, K[v:v + 1], w2c[v:v + 1])
        fg_at, inside = _lookup(fg[v:v + 1], rc)
        violations += (inside[0] & (z[0] > 0) & (source_view != v) & ~fg_at[0])
    return violations <= max_violations


def neighbour_views(w2c: np.ndarray, num_neighbours: int) -> np.ndarray:
    """[V, n] indices of the n views closest in viewing direction to each view (not itself)."""
    forward = w2c[:, 2, :3]
    cos = forward @ forward.T
    np.fill_diagonal(cos, -np.inf)
    return np.argsort(-cos, axis=1)[:, :num_neighbours]


def nearest_surface_depth(depth: np.ndarray, alpha: np.ndarray, *, alpha_threshold: float,
                          window_px: int) -> np.ndarray:
    """[V, H, W] smallest foreground depth in a (2 window_px + 1)^2 window; inf where none.

    At a depth discontinuity a projected point's nearest pixel may show the FAR side; the window
    minimum compares it with the nearest surface around, so an edge is not read as empty space.
    """
    fg_depth = np.where((alpha >= alpha_threshold) & (depth > 0), depth, np.inf).astype(np.float32)
    if window_px <= 0:
        return fg_depth
    neg = torch.from_numpy(-fg_depth)[:, None]
    pooled = torch.nn.functional.max_pool2d(neg, 2 * window_px + 1, stride=1, padding=window_px)
    return -pooled[:, 0].numpy()


def depth_consensus_keep(xyz: np.ndarray, source_view: np.ndarray, depth: np.ndarray,
                         alpha: np.ndarray, K: np.ndarray, w2c: np.ndarray, *,
                         num_neighbours: int = 6, tolerance_px: float = 3.0,
                         max_violations: int = 0, alpha_threshold: float = 0.5,
                         window_px: int = 1) -> np.ndarray:
    """Keep-mask of filter (iii). depth, alpha: [V, H, W] rendered median depth and opacity.

    A neighbour view counts against a point when the point lies in front of the nearest rendered
    surface within `window_px` pixels of its projection by more than `tolerance_px` footprints.
    """
    surface = nearest_surface_depth(depth, alpha, alpha_threshold=alpha_threshold, window_px=window_px)
    neighbours = neighbour_views(w2c, num_neighbours)   # [V, n]
    neighbour_of = np.zeros((len(w2c), len(w2c)), dtype=bool)  # [v, s]: view v is a neighbour of view s
    neighbour_of[neighbours, np.arange(len(w2c))[:, None]] = True
    violations = np.zeros(len(xyz), np.int32)
    # per view, only the points whose source view counts it among its neighbours (n of V views:
    # projecting every point into every view did V / n times the work; same bits per point)
    for v in range(len(w2c)):
        idx = np.flatnonzero(neighbour_of[v, source_view])
        if len(idx) == 0:
            continue
        rc, z = project(xyz[idx], K[v:v + 1], w2c[v:v + 1])
        d_at, inside = _lookup(surface[v:v + 1], rc)
        footprint = z / K[v, 0, 0]                          # world size of one pixel at depth z
        in_front = inside & (z > 0) & np.isfinite(d_at) & (z < d_at - tolerance_px * footprint)
        violations[idx] += in_front[0]
    return violations <= max_violations
