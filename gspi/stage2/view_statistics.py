"""How a surface point's colour changes over the lattice views that see it (issue 52).

A matte surface looks alike from every view; a glossy one shows a highlight in the few views
near the mirror direction, and a metal's highlight wears the base colour while a dielectric's
is the light's (white). Per point, over the views that see it (``project_to_views``: the
depth test Stage II's A5 condition and ``pixel_feature_spread`` use), from linear radiance:

    peak_gain   luminance of the brightest view minus the median luminance
    spread      standard deviation of the luminance
    tint        chroma of the brightest view minus the median colour's chroma (3 channels),
                chroma = rgb / luminance (0 for a black colour)

Luminance is Rec. 709's (``LUMINANCE``). A point seen by fewer than two views gets zeros.
``cross_view_radiance`` computes them for exact lattice renders (training, the oracle) and for a
2DGS asset's renders alike, so the probe can say what Stage 0 takes away.

**Neighbourhood means** (``stage2.data.cross_view_neighbourhood``): a glossy surface shows its
highlight on a minority of its points (measured on the controlled pairs' exact renders), so a point
takes the mean of the statistic, and of Top-RGB, over its k nearest points of the object
(``NEIGHBOURHOOD_KS``: about 1 % and 8 % of its surface). The neighbours are counted in a seeded
subset of ``NEIGHBOURHOOD_POINTS`` of the object's own points, in training (the GT cloud) as at
inference (Stage I's cloud): the same share of the surface whatever the cloud's density; a point
outside the subset takes its nearest subset point's means (the cloud holds ~10^5 points, the means
are smooth over ~1 % of the surface, and computing them per point would cost ~50x more). A per-point
reader (issue 52's cue oracle) reads the metal class and roughness better with these means, and
orders the controlled pairs by a wider gap.
"""
from __future__ import annotations

import numpy as np

from gspi.stage2.lattice_cameras import LatticeCameras, project_to_views

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
FIELDS = ("peak_gain", "spread", "tint_r", "tint_g", "tint_b")
NEIGHBOURHOOD_POINTS = 3000  # the object's seeded subset the neighbours are counted in
NEIGHBOURHOOD_KS = (32, 256)  # k nearest of that subset: ~1 % and ~8 % of the object's surface
NEIGHBOURHOOD_SEED = 0  # the subset's seed, the same in training and at inference
NEIGHBOURHOOD_WIDTH = len(NEIGHBOURHOOD_KS) * (len(FIELDS) + 3)  # the statistic's and Top-RGB's means


def chroma(rgb: np.ndarray) -> np.ndarray:
    """[..., 3] rgb / luminance (0 where the luminance is 0)."""
    lum = rgb @ LUMINANCE
    return np.where(lum[..., None] > 0, rgb / np.where(lum > 0, lum, 1.0)[..., None], 0.0)


def radiance_statistics(colours: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """[n, 5] ``FIELDS`` of colours [V, n, 3] (linear) over the views with ``seen`` [V, n]."""
    lum = np.where(seen, colours @ LUMINANCE, np.nan)
    count = seen.sum(axis=0)
    ok = count >= 2
    out = np.zeros((colours.shape[1], len(FIELDS)), dtype=np.float64)
    if not ok.any():
        return out.astype(np.float32)
    lum, col, sn = lum[:, ok], colours[:, ok], seen[:, ok]
    brightest = np.nanargmax(lum, axis=0)
    cols = np.arange(lum.shape[1])
    median_lum = np.nanmedian(lum, axis=0)
    median_rgb = np.nanmedian(np.where(sn[..., None], col, np.nan), axis=0)
    out[ok, 0] = lum[brightest, cols] - median_lum
    out[ok, 1] = np.nanstd(lum, axis=0)
    out[ok, 2:5] = chroma(col[brightest, cols]) - chroma(median_rgb)
    return out.astype(np.float32)


def condition_features(stats: np.ndarray) -> np.ndarray:
    """[n, 5] the statistic as a Stage II condition (``stage2.data.cross_view_radiance``): gain and
    spread as log(1 + x) (radiance has no upper bound; a highlight is 1-3 above its surface), tint as is."""
    return np.concatenate([np.log1p(np.maximum(stats[:, :2], 0.0)), stats[:, 2:]], axis=1).astype(np.float32)


def cross_view_radiance(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray, *,
                        tol_pixels: float = 2.0, chunk: int = 16384) -> np.ndarray:
    """[n, 5] ``FIELDS`` per point xyz [n, 3] from linear renders [V, H, W, 3] and depths [V, H, W]."""
    out = np.zeros((len(xyz), len(FIELDS)), dtype=np.float32)
    views = np.arange(len(images))[:, None]
    for s in range(0, len(xyz), chunk):
        row, col, _, visible = project_to_views(cams, depth, xyz[s:s + chunk], tol_pixels=tol_pixels)
        out[s:s + chunk] = radiance_statistics(images[views, row, col].astype(np.float64), visible)
    return out


def radiance_condition(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray, *,
                       tol_pixels: float = 2.0) -> np.ndarray:
    """[n, 5] ``condition_features(cross_view_radiance(...))``: Stage II's condition, the same in
    training (GT lattice images and depth) and at inference (the asset's renders and their depth)."""
    return condition_features(cross_view_radiance(images, depth, cams, xyz, tol_pixels=tol_pixels))


def neighbourhood_mean(subset_xyz: np.ndarray, values: np.ndarray, xyz: np.ndarray, k: int,
                       chunk: int = 4096) -> np.ndarray:
    """[n, d] for each point of ``xyz`` [n, 3], the mean of ``values`` [m, d] over its ``k`` nearest
    points of ``subset_xyz`` [m, 3] (all of them when k >= m; a point of the subset counts itself),
    by scipy's cKDTree."""
    from scipy.spatial import cKDTree

    k = min(k, len(subset_xyz))
    tree = cKDTree(subset_xyz)
    out = np.empty((len(xyz), values.shape[1]), dtype=np.float64)
    for s in range(0, len(xyz), chunk):
        _, idx = tree.query(xyz[s:s + chunk], k=k)
        out[s:s + chunk] = values[idx.reshape(-1, k)].mean(axis=1)
    return out.astype(np.float32)


def neighbourhood_subset(num_points: int) -> np.ndarray:
    """Sorted indices of the object's points the neighbourhoods are counted in: a seeded uniform
    subset of ``NEIGHBOURHOOD_POINTS`` (all points when there are fewer)."""
    if num_points <= NEIGHBOURHOOD_POINTS:
        return np.arange(num_points)
    rng = np.random.default_rng(NEIGHBOURHOOD_SEED)
    return np.sort(rng.choice(num_points, size=NEIGHBOURHOOD_POINTS, replace=False))


def neighbourhood_table(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray,
                        top_rgb: np.ndarray, *, tol_pixels: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """(subset xyz [m, 3], its rows [m, NEIGHBOURHOOD_WIDTH]) of the object's cloud xyz [n, 3] with
    its Top-RGB [n, 3]: on ``neighbourhood_subset``, ``radiance_condition`` (read from linear renders
    [V, H, W, 3] and depths [V, H, W]) and Top-RGB, each point's means over its k nearest subset
    points for each k of ``NEIGHBOURHOOD_KS`` (the cue oracle's neighbourhood features)."""
    sub = neighbourhood_subset(len(xyz))
    values = np.concatenate([radiance_condition(images, depth, cams, xyz[sub], tol_pixels=tol_pixels),
                             np.asarray(top_rgb, dtype=np.float32)[sub]], axis=1)
    return xyz[sub], np.concatenate([neighbourhood_mean(xyz[sub], values, xyz[sub], k) for k in NEIGHBOURHOOD_KS],
                                    axis=1)


def neighbourhood_lookup(table: tuple[np.ndarray, np.ndarray], xyz: np.ndarray) -> np.ndarray:
    """[n, NEIGHBOURHOOD_WIDTH] each point's row of its nearest subset point (``neighbourhood_table``)."""
    return neighbourhood_mean(table[0], table[1], xyz, 1)


def neighbourhood_condition(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray,
                            top_rgb: np.ndarray, *, tol_pixels: float = 2.0) -> np.ndarray:
    """[n, NEIGHBOURHOOD_WIDTH] ``stage2.data.cross_view_neighbourhood`` of every point of the cloud
    xyz [n, 3]: its nearest subset point's neighbourhood means (``neighbourhood_table``)."""
    return neighbourhood_lookup(neighbourhood_table(images, depth, cams, xyz, top_rgb, tol_pixels=tol_pixels), xyz)
