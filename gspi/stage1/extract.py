"""Stage I: render the canonical lattice views of a 2DGS asset, unproject, filter.

    points, renders, stats = extract_point_cloud(gaussians, Stage1Config(image_size=128))

The 32 lattice views are rendered by ``gspi.gaussians.lattice_render.render_lattice`` (the
same renderer and cameras as Stage 0 and the dataset's ``train`` split); the renders travel
on to Stages II and III with their cameras (:class:`LatticeRenders`). Foreground pixels
(rendered alpha >= ``alpha_threshold``) of each view are unprojected with the rendered MEDIAN
depth (2DGS's surface depth) into world points; each keeps its view, pixel and rendered RGB.
Then the filters of ``gspi.stage1.filters``, each switchable, with a per-step report
(``gspi.stage1.report``), and an optional seeded subsample (``max_points``, a CPU-scale knob).
"""
from __future__ import annotations

import time
from typing import Callable, Optional

import numpy as np
import torch
from scipy.spatial import cKDTree

from gspi.gaussians.cameras import unproject
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.lattice_render import LatticeRenders, render_lattice as render_lattice_maps
from gspi.stage1 import filters
from gspi.stage1.config import Stage1Config
from gspi.point_cloud import PointCloud
from gspi.stage1.report import source_footprint, step_stats

__all__ = ["Stage1Config", "LatticeRenders", "render_lattice", "unproject_renders", "apply_filters",
           "maybe_subsample", "extract_point_cloud"]


def render_lattice(gaussians: Gaussians2D, cfg: Stage1Config) -> LatticeRenders:
    """RGB, alpha and median depth of Stage I's lattice (``cfg.lattice``, ``cfg.image_size``)."""
    return render_lattice_maps(gaussians, image_size=cfg.image_size, lattice=cfg.lattice)


def unproject_renders(renders: LatticeRenders, alpha_threshold: float) -> PointCloud:
    """One point per foreground pixel of every view, with its source view, pixel and RGB."""
    parts = []
    for v in range(len(renders.K)):
        fg = (renders.alpha[v] >= alpha_threshold) & (renders.depth[v] > 0)
        rows, cols = np.nonzero(fg)
        xyz = unproject(torch.from_numpy(renders.depth[v]), torch.from_numpy(renders.K[v]),
                        torch.from_numpy(renders.w2c[v])).numpy()
        parts.append((xyz[rows, cols], np.full(len(rows), v, np.int32),
                      np.stack([rows, cols], -1).astype(np.int32), renders.rgb[v][rows, cols]))
    xyz, view, pixel, rgb = (np.concatenate(p) for p in zip(*parts))
    return PointCloud(xyz=xyz.astype(np.float32), view=view, pixel=pixel,
                      rgb=rgb.astype(np.float32), image_size=renders.image_size)


def filter_steps(renders: LatticeRenders, cfg: Stage1Config
                 ) -> list[tuple[str, Callable[[PointCloud], np.ndarray]]]:
    """The enabled filters in cascade order: (name, points -> keep-mask [P] bool)."""
    steps = []
    if cfg.outliers.enabled:
        c = cfg.outliers
        steps.append(("statistical_outliers", lambda p: filters.statistical_outliers_keep(
            p.xyz, k=c.k, std_ratio=c.std_ratio)))
    if cfg.mask_consistency.enabled:
        m = cfg.mask_consistency
        steps.append(("mask_consistency", lambda p: filters.mask_consistency_keep(
            p.xyz, p.view, renders.alpha, renders.K, renders.w2c, alpha_threshold=cfg.alpha_threshold,
            max_violations=m.max_violations, dilate_px=m.dilate_px)))
    if cfg.depth_consensus.enabled:
        d = cfg.depth_consensus
        steps.append(("depth_consensus", lambda p: filters.depth_consensus_keep(
            p.xyz, p.view, renders.depth, renders.alpha, renders.K, renders.w2c,
            num_neighbours=d.num_neighbours, tolerance_px=d.tolerance_px,
            max_violations=d.max_violations, alpha_threshold=cfg.alpha_threshold,
            window_px=d.window_px)))
    return steps


def apply_filters(points: PointCloud, renders: LatticeRenders, cfg: Stage1Config,
                  reference: Optional[np.ndarray] = None) -> tuple[PointCloud, list[dict]]:
    """Cascades the enabled filters; per step what it removed and, with ``reference`` [R, 3]
    (GT surface samples), the distances of the kept and removed points (``gspi.stage1.report``)."""
    # the filters remove points and never move them: each point's distance to the reference and its
    # footprint are computed once and follow it through the steps
    dist = None if reference is None else cKDTree(reference).query(points.xyz, k=1)[0]
    footprint = source_footprint(points.xyz.astype(np.float64), points.view, renders.K, renders.w2c)
    report = [{"step": "unprojected", **step_stats(dist, footprint)}]
    for name, keep_fn in filter_steps(renders, cfg):
        keep = keep_fn(points)
        report.append({"step": name, **step_stats(dist, footprint, removed=~keep)})
        points, footprint = points.subset(keep), footprint[keep]
        dist = None if dist is None else dist[keep]
    return points, report


MIN_VIEW_FRACTION = 0.25  # of the lattice views that must contribute points to the cloud


def check_cloud_covers_lattice(points: PointCloud, renders: LatticeRenders) -> None:
    """An object seen from a hemisphere of cameras shows up in most of them: a cloud drawn from
    fewer than a quarter of the lattice views (an asset that is mostly out of frame or behind
    the cameras) would be distilled from a few views and scored as a normal run."""
    views = np.unique(points.view).size
    if views < MIN_VIEW_FRACTION * renders.num_views:
        raise ValueError(f"Stage I: the point cloud comes from {views} of {renders.num_views} lattice "
                         f"views (< {MIN_VIEW_FRACTION:.0%}); the asset does not cover the lattice "
                         "(check its scale and position: objects must fit the unit sphere)")


def maybe_subsample(points: PointCloud, max_points: Optional[int], seed: int) -> PointCloud:
    """A seeded uniform subsample of ``max_points`` points (kept in their original order); all
    points when ``max_points`` is None or not below the count.

    A CPU-scale knob, not the paper's method: the paper runs Stage II on the whole cloud.
    """
    if max_points is None or max_points >= len(points):
        return points
    if max_points <= 0:
        raise ValueError(f"stage1.max_points must be a positive integer or null, got {max_points}")
    idx = np.random.default_rng(seed).choice(len(points), size=max_points, replace=False)
    return points.subset(np.sort(idx))


def extract_point_cloud(gaussians: Gaussians2D, cfg: Stage1Config, *,
                        reference: Optional[np.ndarray] = None
                        ) -> tuple[PointCloud, LatticeRenders, dict]:
    """Stage I end to end. ``reference`` [R, 3] (optional) = GT surface samples for the report.

    Returns:
        (points, renders, stats): stats = {"config", "filters" (per-step report), "num_points",
        "seconds" {"render", "filters", "total"}}.
    """
    start = time.perf_counter()
    renders = render_lattice(gaussians, cfg)
    t_render = time.perf_counter() - start
    points = unproject_renders(renders, cfg.alpha_threshold)
    points, steps = apply_filters(points, renders, cfg, reference)
    if len(points) == 0:
        raise ValueError("Stage I kept no point: the asset renders no foreground on the lattice "
                         f"(alpha >= {cfg.alpha_threshold}); check the asset's scale and position")
    check_cloud_covers_lattice(points, renders)
    num_filtered = len(points)
    points = maybe_subsample(points, cfg.max_points, cfg.seed)
    total = time.perf_counter() - start
    stats = {"config": cfg.to_dict(), "filters": steps, "num_filtered": num_filtered,
             "num_points": len(points),
             "seconds": {"render": t_render, "filters": total - t_render, "total": total}}
    return points, renders, stats
