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
"""
from __future__ import annotations

import numpy as np

from gspi.stage2.lattice_cameras import LatticeCameras, project_to_views

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
FIELDS = ("peak_gain", "spread", "tint_r", "tint_g", "tint_b")


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
