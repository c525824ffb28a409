"""Stage I: render the canonical lattice views of a 2DGS asset, unproject, filter.

    points, stats = extract_point_cloud(gaussians, Stage1Config(image_size=128))

Foreground pixels (rendered alpha >= `alpha_threshold`) of each of the V = 32 lattice views are
unprojected with the rendered MEDIAN depth (2DGS's surface depth) into world points; each keeps
its view, pixel and rendered RGB. Then the filters of `gspi.stage1.filters`, each switchable.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
import torch
from scipy.spatial import cKDTree

from gspi.data.lattice import lattice_cameras
from gspi.gaussians.cameras import unproject
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import render_gaussians
from gspi.stage1 import filters
from gspi.stage1.point_cloud import NUM_LATTICE_VIEWS, PointCloud


@dataclass
class OutlierConfig:
    enabled: bool = True
    k: int = 16               # neighbours for the mean distance
    std_ratio: float = 2.0    # keep mean_dist <= mean + std_ratio * std


@dataclass
class MaskConsistencyConfig:
    enabled: bool = True
    max_violations: int = 1   # views in which the point may land on background
    dilate_px: int = 1        # silhouette tolerance


@dataclass
class DepthConsensusConfig:
    enabled: bool = True
    num_neighbours: int = 6   # closest lattice views to the source view
    tolerance_px: float = 3.0  # in pixel footprints at the point's depth
    max_violations: int = 1   # neighbour views that see empty space where the point is


@dataclass
class Stage1Config:
    image_size: int = 128          # lattice render size (paper: 512)
    num_views: int = NUM_LATTICE_VIEWS
    radius: float = 3.0            # lattice camera distance (gspi/data/lattice.py)
    fov_deg: float = 45.0
    alpha_threshold: float = 0.5   # foreground = rendered opacity >= this
    outliers: OutlierConfig = field(default_factory=OutlierConfig)
    mask_consistency: MaskConsistencyConfig = field(default_factory=MaskConsistencyConfig)
    depth_consensus: DepthConsensusConfig = field(default_factory=DepthConsensusConfig)


@dataclass
class LatticeRenders:
    rgb: np.ndarray     # [V, H, W, 3] linear
    alpha: np.ndarray   # [V, H, W]
    depth: np.ndarray   # [V, H, W] median depth (camera z)
    K: np.ndarray       # [V, 3, 3]
    w2c: np.ndarray     # [V, 4, 4]


def render_lattice(gaussians: Gaussians2D, cfg: Stage1Config) -> LatticeRenders:
    """RGB, alpha and median depth of the canonical lattice views (no gradients)."""
    K, w2c = lattice_cameras(num_views=cfg.num_views, radius=cfg.radius, fov_deg=cfg.fov_deg,
                             width=cfg.image_size, height=cfg.image_size)
    with torch.no_grad():
        out = render_gaussians(gaussians, torch.from_numpy(w2c).float(),
                               torch.from_numpy(K).float(), cfg.image_size, cfg.image_size)
    return LatticeRenders(rgb=out.rgb.numpy(), alpha=out.alpha[..., 0].numpy(),
                          depth=out.depth_median[..., 0].numpy(), K=K, w2c=w2c)


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
                      rgb=rgb.astype(np.float32))


def surface_distance_stats(xyz: np.ndarray, reference: np.ndarray | None) -> dict:
    """Count and distances to a reference surface sample (e.g. the GT point cloud)."""
    stats = {"count": int(len(xyz))}
    if reference is not None and len(xyz):
        d, _ = cKDTree(reference).query(xyz, k=1)
        stats.update(mean_dist=float(d.mean()), median_dist=float(np.median(d)),
                     p95_dist=float(np.percentile(d, 95)), max_dist=float(d.max()))
    return stats


def apply_filters(points: PointCloud, renders: LatticeRenders, cfg: Stage1Config,
                  reference: np.ndarray | None = None) -> tuple[PointCloud, list[dict]]:
    """Cascade the enabled filters; per step, what it removed and the surface distances."""
    steps = [{"step": "unprojected", **surface_distance_stats(points.xyz, reference)}]
    if cfg.outliers.enabled:
        keep = filters.statistical_outliers_keep(points.xyz, k=cfg.outliers.k,
                                                 std_ratio=cfg.outliers.std_ratio)
        points = points.subset(keep)
        steps.append({"step": "statistical_outliers", "removed": int((~keep).sum()),
                      **surface_distance_stats(points.xyz, reference)})
    if cfg.mask_consistency.enabled:
        c = cfg.mask_consistency
        keep = filters.mask_consistency_keep(points.xyz, points.view, renders.alpha, renders.K,
                                             renders.w2c, alpha_threshold=cfg.alpha_threshold,
                                             max_violations=c.max_violations,
                                             dilate_px=c.dilate_px)
        points = points.subset(keep)
        steps.append({"step": "mask_consistency", "removed": int((~keep).sum()),
                      **surface_distance_stats(points.xyz, reference)})
    if cfg.depth_consensus.enabled:
        c = cfg.depth_consensus
        keep = filters.depth_consensus_keep(points.xyz, points.view, renders.depth, renders.alpha,
                                            renders.K, renders.w2c,
                                            num_neighbours=c.num_neighbours,
                                            tolerance_px=c.tolerance_px,
                                            max_violations=c.max_violations,
                                            alpha_threshold=cfg.alpha_threshold)
        points = points.subset(keep)
        steps.append({"step": "depth_consensus", "removed": int((~keep).sum()),
                      **surface_distance_stats(points.xyz, reference)})
    return points, steps


def extract_point_cloud(gaussians: Gaussians2D, cfg: Stage1Config, *,
                        reference: np.ndarray | None = None
                        ) -> tuple[PointCloud, LatticeRenders, dict]:
    """Stage I end to end. `reference` [R, 3] (optional) = GT surface samples for the report."""
    start = time.perf_counter()
    renders = render_lattice(gaussians, cfg)
    points = unproject_renders(renders, cfg.alpha_threshold)
    points, steps = apply_filters(points, renders, cfg, reference)
    if len(points) == 0:
        raise ValueError("Stage I kept no point: the asset renders no foreground on the lattice "
                         f"(alpha >= {cfg.alpha_threshold}); check the asset's scale and position")
    stats = {"config": asdict(cfg), "filters": steps, "num_points": len(points),
             "seconds": time.perf_counter() - start}
    return points, renders, stats
