"""Stage II inference on a GENERATED (Stage I) point cloud of a 2DGS asset.

Training reads GT point clouds (``gspi.stage2.data``); inference reads what Stage I made from
the asset: the points with their source view/pixel and observed RGB, and the asset's own 32
lattice renders (RGB for the global prior and A5's multi-view colours, median depth for A5's
visibility). The conditions are built exactly as in training (docs/STAGE2.md "Conditioning"):

* ``top_rgb_onehot`` / ``top_rgb``: ``linear_to_srgb(clamp(rgb, 0, 1))`` (+ one-hot of v*);
* ``multiview`` (A5): the lattice renders replace the GT views and GT depth;
* ``pixel_features``: the encoder's unpooled map of the asset's render of the source view,
  sampled at the source pixel (``gspi.stage2.data.sample_pixel_features``, as in training);
* ``cross_view_radiance``: the point's radiance over the renders that see it
  (``gspi.stage2.view_statistics``; the renders' linear radiance and depth);
* ``cross_view_neighbourhood``: its means (and Top-RGB's) over the point's neighbours in a seeded
  subset of the cloud (``view_statistics.neighbourhood_condition``), as in training;
* ``pixel_feature_spread``: that map's spread over the renders that see the point, A5's
  visibility on the renders' depth (``gspi.stage2.data.feature_spread_over_views``);
* global prior: the frozen encoder on the asset's lattice renders (sRGB of clamped linear).

``max_points`` (CPU-scale knob, default None = the paper's whole cloud) samples a seeded
uniform subset, and the other points take their nearest sampled neighbour's prediction;
``points_per_gaussian`` caps it at that many points per Gaussian of the asset (``for_asset``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import ClassVar, Optional

import numpy as np
import torch
from torch import Tensor

from eval.common.colorspace import linear_to_srgb
from gspi.data.lattice import NUM_LATTICE_VIEWS
from gspi.gaussians.lattice_render import LatticeRenders
from gspi.point_cloud import PointCloud, nearest_fill
from gspi.stage2.data import (LatticeCameras, PointDataConfig, feature_spread_over_views, local_condition_dim,
                              multiview_condition_from_views, sample_pixel_features, srgb_top_rgb)
from gspi.stage2.encoders import pool_grid
from gspi.stage2.light_condition import readout_lookup
from gspi.stage2.light_views import LIGHT_VIEWS
from gspi.stage2.model import RCWDenoiser
from gspi.stage2.oom import run_with_chunk_halving
from gspi.stage2.sampler import mean_point_pbr
from gspi.stage2.view_statistics import neighbourhood_condition, radiance_condition


@dataclass(frozen=True)
class InferenceConfig:
    """``stage2.inference``: how the whole cloud is sampled."""

    num_steps: int = 50  # DDIM steps (paper: 50)
    guidance_scale: float = 1.0  # classifier-free guidance (1 = off, the paper)
    num_samples: int = 1  # DDIM samples averaged per point (1 = the paper)
    max_points: Optional[int] = None  # None = whole cloud (paper); else seeded subset + 1-NN fill
    points_per_gaussian: Optional[float] = None  # caps max_points at this many x the asset's Gaussians
    patch_points: Optional[int] = None  # None = whole cloud at once (paper); else k-NN patches (gspi.stage2.patches)
    patch_coverage: float = 2.0  # patches per point on average (patch_points only)
    write_chunk: Optional[int] = 32768  # points per Write chunk (memory bound)
    seed: int = 0
    light_views: str = "photos"  # a light-aware model (stage2.data.light_readout) reads the light in the scene's
    #                              photos at the lattice cameras where it has them (else the renders) | renders

    CHOICES: ClassVar[dict] = {"light_views": LIGHT_VIEWS}

    @classmethod
    def from_mapping(cls, cfg) -> "InferenceConfig":
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ValueError(f"stage2.inference: unknown keys {unknown} (known: {sorted(known)})")
        config = cls(**dict(cfg))
        check_points_per_gaussian(config.points_per_gaussian, "stage2.inference.points_per_gaussian")
        return config

    def for_asset(self, num_gaussians: Optional[int]) -> "InferenceConfig":
        """This config with ``max_points`` capped at ``points_per_gaussian`` x ``num_gaussians``:
        Stage III gives each Gaussian the mean of the points that land on it, so a few points per
        Gaussian carry what the whole cloud does (the demo: docs/log/speed/asset_budget.json)."""
        return replace(self, max_points=asset_point_budget(self.max_points, self.points_per_gaussian, num_gaussians))


def check_points_per_gaussian(value: Optional[float], key: str) -> None:
    """A points-per-Gaussian budget is positive or null; else an error naming ``key``."""
    if value is not None and not value > 0:
        raise ValueError(f"{key} must be positive or null, got {value}")


def asset_point_budget(max_points: Optional[int], points_per_gaussian: Optional[float],
                       num_gaussians: Optional[int]) -> Optional[int]:
    """``max_points`` capped at ``points_per_gaussian`` x ``num_gaussians`` (at least 1); unchanged
    when either is None. Stage II's sampled subset and the light read-out's read points."""
    if points_per_gaussian is None or num_gaussians is None:
        return max_points
    cap = max(1, int(round(points_per_gaussian * num_gaussians)))
    return cap if max_points is None else min(cap, max_points)


def lattice_srgb(rgb_linear: Tensor | np.ndarray) -> Tensor:
    """[V, H, W, 3] linear renders -> [V, 3, H, W] sRGB in [0, 1] (the encoders' input)."""
    rgb = torch.as_tensor(np.asarray(rgb_linear), dtype=torch.float32)
    return linear_to_srgb(rgb.clamp(0.0, 1.0)).permute(0, 3, 1, 2).contiguous()


def prior_features(encoder, rgb_linear: np.ndarray, *, unpooled: bool = False) -> Optional[Tensor]:
    """[32, D, 5, 5] global-prior features of the asset's lattice renders, None without a prior;
    ``unpooled``: the [32, D, g, g] maps they pool (``stage2.data.pixel_features``)."""
    if encoder.feature_dim == 0:
        return None
    if len(rgb_linear) != NUM_LATTICE_VIEWS:
        raise ValueError(f"the global prior needs the {NUM_LATTICE_VIEWS} lattice renders, got {len(rgb_linear)}")
    with torch.no_grad():
        images = lattice_srgb(rgb_linear)
        return (encoder.encode_map(images) if unpooled else encoder.encode(images)).float()


def point_conditions(points: PointCloud, mode: str, renders: LatticeRenders, *,
                     tol_pixels: float = 2.0, feature_maps: Optional[Tensor] = None,
                     pixel_features: bool = True, pixel_feature_spread: bool = False,
                     cross_view_radiance: bool = False, cross_view_neighbourhood: bool = False,
                     light_table: Optional[tuple[np.ndarray, np.ndarray]] = None) -> np.ndarray:
    """[P, C] local condition of Stage I points (C = 35 / 3 / 128, as in training); A5's
    multi-view colours come from Stage I's ``renders`` (their maps and cameras).
    ``cross_view_radiance``: + 5, the point's radiance over the renders that see it (issue 52);
    ``cross_view_neighbourhood``: + 16, its and Top-RGB's means over each point's neighbours.
    ``light_table``: + 7, the light read-out's table of the cloud (``light_condition.readout_table``
    under the estimated light), each point's nearest row (issue 66).
    ``feature_maps`` [32, D, g, g]: the encoder's maps of the renders; with ``pixel_features``
    sampled at each point's source pixel and appended (+D), with ``pixel_feature_spread`` their
    spread over the renders that see the point appended (+D), in that order as in training."""
    local_condition_dim(mode)
    height, width = renders.image_size
    cams = LatticeCameras.from_renders(renders)
    top = srgb_top_rgb(points.rgb)
    if mode == "top_rgb":
        cond = top
    elif mode == "top_rgb_onehot":
        onehot = np.eye(NUM_LATTICE_VIEWS, dtype=np.float32)[points.view]
        cond = np.concatenate([top, onehot], axis=1)
    else:
        cond = multiview_condition_from_views(srgb_top_rgb(renders.rgb), renders.depth, cams,
                                              points.xyz.astype(np.float64), tol_pixels=tol_pixels)
    if cross_view_radiance:  # from the renders' linear radiance and depth, as training from the GT views'
        cond = np.concatenate([cond, radiance_condition(np.asarray(renders.rgb), np.asarray(renders.depth), cams,
                                                        points.xyz.astype(np.float64), tol_pixels=tol_pixels)], axis=1)
    if cross_view_neighbourhood:  # over a seeded subset of Stage I's cloud, as training over the GT cloud's
        cond = np.concatenate([cond, neighbourhood_condition(np.asarray(renders.rgb), np.asarray(renders.depth), cams,
                                                             points.xyz.astype(np.float64), top,
                                                             tol_pixels=tol_pixels)], axis=1)
    if light_table is not None:
        cond = np.concatenate([cond, readout_lookup(light_table, points.xyz.astype(np.float64))], axis=1)
    if feature_maps is None:
        return cond
    parts = [cond]
    if pixel_features:
        parts.append(sample_pixel_features(feature_maps, points.view, points.pixel, (height, width)))
    if pixel_feature_spread:
        parts.append(feature_spread_over_views(feature_maps, np.asarray(renders.depth), cams,
                                               points.xyz.astype(np.float64), tol_pixels=tol_pixels))
    return np.concatenate(parts, axis=1)


def subsample_indices(num_points: int, max_points: Optional[int], seed: int) -> Optional[np.ndarray]:
    """Sorted seeded uniform subset of ``range(num_points)``, None when no subsampling is needed."""
    if max_points is None or num_points <= max_points:
        return None
    if max_points <= 0:
        raise ValueError(f"stage2.inference.max_points must be positive or null, got {max_points}")
    return np.sort(np.random.default_rng(seed).choice(num_points, size=max_points, replace=False))


def predict_generated_points(model: RCWDenoiser, points: PointCloud, renders: LatticeRenders, *,
                             data: PointDataConfig, encoder, cfg: InferenceConfig,
                             light_table: Optional[tuple[np.ndarray, np.ndarray]] = None,
                             device: Optional[torch.device] = None) -> tuple[np.ndarray, dict]:
    """Stage II on a Stage I cloud and its lattice renders: [P, 5] (albedo sRGB RGB, roughness,
    metallic) in [0, 1] + stats. ``data``: the model's ``stage2.data`` (its conditions, as trained);
    ``light_table``: the light read-out's table when ``data.light_readout`` (``light_fit.inference_light_table``).
    ``device``: where the sampling runs (None: the model's, as before); the conditions and prior
    features move there once, the PBR comes back as numpy."""
    t0 = time.perf_counter()
    if data.light_readout != (light_table is not None):
        raise ValueError(f"stage2.data.light_readout={data.light_readout} but "
                         f"{'no' if light_table is None else 'a'} light read-out table was given")
    width = data.condition_width(encoder.feature_dim)
    if model.config.local_cond_dim != width:
        raise ValueError(f"the Stage II model expects a {model.config.local_cond_dim}-dim local condition, "
                         f"stage2.data.local_condition={data.local_condition!r} (cross_view_radiance="
                         f"{data.cross_view_radiance}, cross_view_neighbourhood={data.cross_view_neighbourhood}, "
                         f"light_readout={data.light_readout}, pixel_features={data.pixel_features}, "
                         f"pixel_feature_spread={data.pixel_feature_spread}) gives {width}")
    # with pixel features the encoder runs once: the grid is the pooled map, as encode() computes it
    maps = prior_features(encoder, renders.rgb, unpooled=True) if data.needs_feature_maps else None
    feats = pool_grid(maps) if maps is not None else prior_features(encoder, renders.rgb)
    if (feats is None) != (model.config.global_token_dim == 0):
        raise ValueError(f"prior encoder {getattr(encoder, 'name', encoder)!r} does not match the model "
                         f"(global_token_dim={model.config.global_token_dim})")
    sub = subsample_indices(len(points), cfg.max_points, cfg.seed)
    pts = points if sub is None else points.subset(sub)
    cond = point_conditions(pts, data.local_condition, renders, tol_pixels=float(data.visibility_tol_pixels),
                            feature_maps=maps, pixel_features=data.pixel_features,
                            pixel_feature_spread=data.pixel_feature_spread,
                            cross_view_radiance=data.cross_view_radiance,
                            cross_view_neighbourhood=data.cross_view_neighbourhood, light_table=light_table)
    t_cond = time.perf_counter() - t0
    model = model if device is None else model.to(device)

    def sample_all(chunk: Optional[int]) -> np.ndarray:
        return mean_point_pbr(model, pts.xyz, cond, feats, num_samples=cfg.num_samples, seed=cfg.seed,
                              num_steps=cfg.num_steps, write_chunk=chunk, guidance_scale=cfg.guidance_scale,
                              patch_points=cfg.patch_points, patch_coverage=cfg.patch_coverage,
                              device=device)

    pbr, chunk = run_with_chunk_halving(sample_all, cfg.write_chunk, len(pts))
    if sub is not None:
        pbr = nearest_fill(pts.xyz, pbr, points.xyz)
    stats = {"num_points": len(points), "num_sampled": len(pts), "num_steps": cfg.num_steps,
             "num_samples": max(1, cfg.num_samples), "guidance_scale": cfg.guidance_scale,
             **({"patch_points": cfg.patch_points, "patch_coverage": cfg.patch_coverage} if cfg.patch_points else {}),
             "seconds_conditions": round(t_cond, 3), "seconds": round(time.perf_counter() - t0, 3)}
    if chunk != cfg.write_chunk:  # shrunk after running out of GPU memory
        stats["write_chunk"] = chunk
    return pbr, stats
