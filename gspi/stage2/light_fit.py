"""The training-free read-out as a method's materials (``method=light_fit``, issue 66): on a
Stage I cloud and its lattice renders, estimate the capture light among candidate environments
(``gspi.light.estimate``), then read each point's material against it (``gspi.light.readout``:
the grid fit pooled over neighbours, posterior mean). Normals: the plane of each point's nearest
points of the Stage I cloud (``cloud_normals``; the asset's surfel normals are too noisy).

``predict_light_fit`` returns what Stage II's ``predict_generated_points`` returns ([P, 5]: albedo
sRGB, roughness, metallic; stats), so the pipeline's Stage III takes either.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import torch

from eval.common.colorspace import linear_to_srgb
from eval.relight import PrefilteredEnvironment
from gspi.light.estimate import TOLD_MARGIN, estimate_light, seen_subset
from gspi.light.refine import refine_light
from gspi.light.readout import (NEIGHBOURS, POSTERIOR_TEMPERATURE, fit_grid, fit_grid_normal_search, metal_evidence,
                                metal_ruled_out, pool_neighbours, read_posterior, without_metal)
from gspi.point_cloud import PointCloud, nearest_fill
from gspi.stage2.infer import asset_point_budget, check_points_per_gaussian, subsample_indices
from gspi.stage2.lattice_cameras import LatticeCameras
from gspi.stage2.light_condition import candidate_lights, cloud_normals
from gspi.stage2.light_views import LIGHT_VIEWS, LatticePhotos, observe_points, views_to_read

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LightFitConfig:
    """conf/method/light_fit.yaml's keys (the read-out's settings are ``gspi.light.readout``'s)."""

    candidates: Any = "procedural"   # the lights it may pick: procedural | polyhaven | [names or EXR paths]
    env_height: int = 64             # rows of each candidate's lat-long map
    max_points: int | None = 20000   # points read (seeded subset, 1-NN fill); None: all
    points_per_gaussian: float | None = None  # caps max_points at this many x the asset's Gaussians; None: no cap
    identify_points: int = 2000      # points the light is identified on
    identify_coarse_points: int | None = None  # of them, read by the coarse search over every candidate and turn
    neighbours: int = NEIGHBOURS
    temperature: float = POSTERIOR_TEMPERATURE
    tol_pixels: float = 2.0          # the views' depth test (as Stage II's conditions)
    views: str = "photos"            # read the scene's photos at the lattice cameras (else the renders) | renders
    normal_search_deg: tuple = ()    # rings (degrees) of candidate normals around each cloud normal; () = none
    normal_profile: int = 1          # the searched normals each grid cell takes the best of (1: the single best)
    metal_min_evidence: float | None = None  # no metal anywhere unless allowing it explains the object this many
    #                                          times better (gspi.light.readout.metal_evidence); None: per point only
    light_refine: bool = False       # refine the best candidate by a coarse map fitted to the views (a light in
    #                                  no candidate set: gspi.light.refine), on the identify_points
    seed: int = 0

    @classmethod
    def from_mapping(cls, cfg) -> "LightFitConfig":
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(cfg) - known - {"name", "_target_"})
        if unknown:
            raise ValueError(f"method.{unknown[0]}: unknown light_fit key; allowed: {', '.join(sorted(known))}")
        values = {k: cfg[k] for k in known if k in cfg}
        if isinstance(values.get("candidates"), (list, tuple)):
            values["candidates"] = tuple(str(c) for c in values["candidates"])
        if "normal_search_deg" in values:
            values["normal_search_deg"] = tuple(float(d) for d in values["normal_search_deg"] or ())
        check_points_per_gaussian(values.get("points_per_gaussian"), "method.points_per_gaussian")
        if values.get("views", "photos") not in LIGHT_VIEWS:
            raise ValueError(f"method.views={values['views']!r}: must be one of {', '.join(LIGHT_VIEWS)}")
        return cls(**values)

    @classmethod
    def shipped(cls) -> "LightFitConfig":
        """``method=light_fit`` as shipped: conf/method/light_fit.yaml (what a run without overrides reads)."""
        import yaml

        from eval.common.conf import CONF_DIR

        return cls.from_mapping(yaml.safe_load((Path(CONF_DIR) / "method" / "light_fit.yaml").read_text()))

    def for_asset(self, num_gaussians: int | None) -> "LightFitConfig":
        """This config with ``max_points`` capped at ``points_per_gaussian`` x ``num_gaussians``
        (Stage III gives each Gaussian the mean of its points, as for Stage II's)."""
        return replace(self, max_points=asset_point_budget(self.max_points, self.points_per_gaussian, num_gaussians))


def observe_cloud(points: PointCloud, renders, cfg: LightFitConfig, photos: LatticePhotos | None = None):
    """The views' observations (``PointViews``) of the read points of ``points`` (a seeded subset
    of ``cfg.max_points``, its indices returned, None for all) with the cloud's normals, in
    ``photos`` at the lattice cameras when given, else in the renders."""
    images, depth = views_to_read(renders, photos)
    cams = LatticeCameras.from_renders(renders)
    sub = subsample_indices(len(points), cfg.max_points, cfg.seed)
    pts = points if sub is None else points.subset(sub)
    xyz = pts.xyz.astype(np.float64)
    normal = cloud_normals(points.xyz.astype(np.float64), xyz, cams.centers[pts.view])
    return observe_points(images, depth, cams, xyz, normal, tol_pixels=cfg.tol_pixels), sub


@dataclass
class LightRead:
    """What the read-out knows of one cloud: the read points' observations (``sub`` their indices,
    None for all), the light found, each point's error grid and that grid pooled over neighbours."""

    obs: Any
    sub: np.ndarray | None
    light: Any  # gspi.light.estimate.LightEstimate
    grid: Any   # gspi.light.readout.MaterialGrid
    pooled: torch.Tensor
    seconds: dict
    refined: Any = None  # gspi.light.refine.RefinedLight with method.light_refine, else None

    @property
    def metal_evidence(self) -> float:
        return metal_evidence(self.pooled, self.grid.metallic, self.grid.views > 0)

    def pbr(self, points: PointCloud, temperature: float, *, metal: bool = True) -> np.ndarray:
        """[P, 5] every point's posterior PBR (albedo sRGB, roughness, metallic), 1-NN filled from
        the read points; ``metal=False``: with every metal cell ruled out (metallic exactly 0)."""
        pooled = self.pooled if metal else without_metal(self.pooled, self.grid.metallic)
        albedo, rough, metallic = read_posterior(self.grid, pooled, temperature)
        pbr = torch.cat([linear_to_srgb(albedo), rough[:, None], metallic[:, None]], dim=1).numpy().astype(np.float32)
        if self.sub is None:
            return pbr
        return nearest_fill(points.subset(self.sub).xyz, pbr, points.xyz).astype(np.float32)


def read_light(points: PointCloud, renders, cfg: LightFitConfig, candidates: dict[str, PrefilteredEnvironment],
               photos: LatticePhotos | None = None) -> LightRead:
    """The light estimated among ``candidates`` and every read point's grid against it, in
    ``photos`` at the lattice cameras when given, else in the renders."""
    t0 = time.perf_counter()
    obs, sub = observe_cloud(points, renders, cfg, photos)
    t_obs = time.perf_counter()
    light = estimate_light(obs, candidates, max_points=cfg.identify_points, coarse_points=cfg.identify_coarse_points,
                           seed=cfg.seed)
    pre, rotation, gain, refined = candidates[light.env], light.rotation_deg, light.gain, None
    if cfg.light_refine:
        refined = refine_light(seen_subset(obs, cfg.identify_points, cfg.seed), pre, rotation, gain)
        pre, gain = refined.pre, 1.0
    t_light = time.perf_counter()
    if cfg.normal_search_deg:
        grid = fit_grid_normal_search(obs, pre, rings_deg=cfg.normal_search_deg, profile=cfg.normal_profile,
                                      rotation_deg=rotation, gain=gain)
    else:
        grid = fit_grid(obs, pre, rotation_deg=rotation, gain=gain)
    pooled = pool_neighbours(grid, obs.xyz, k=cfg.neighbours)
    return LightRead(obs, sub, light, grid, pooled, {"observe": round(t_obs - t0, 2), "light": round(t_light - t_obs, 2),
                                                     "grid": round(time.perf_counter() - t_light, 2)}, refined)


def predict_light_fit(points: PointCloud, renders, cfg: LightFitConfig,
                      candidates: dict[str, PrefilteredEnvironment], photos: LatticePhotos | None = None
                      ) -> tuple[np.ndarray, dict]:
    """[P, 5] PBR of every point (albedo sRGB, roughness, metallic) and stats (the light found),
    read in ``photos`` at the lattice cameras when given, else in the renders."""
    read = read_light(points, renders, cfg, candidates, photos)
    t0 = time.perf_counter()
    evidence = read.metal_evidence
    gated = metal_ruled_out(evidence, cfg.metal_min_evidence)
    pbr = read.pbr(points, cfg.temperature, metal=not gated)
    light = read.light
    if not light.told:
        log.warning("light_fit: the light is not told apart from the other candidates (margin %.3f < %.2f): it may be "
                    "in no candidate set, and the read-out then reads materials worse than Stage II does; give its "
                    "capture environment as method.candidates=[<env.exr>] (docs/LIGHT.md)", light.margin, TOLD_MARGIN)
    stats = {"light": {"env": light.env, "rotation_deg": round(light.rotation_deg, 2), "gain": round(light.gain, 4),
                       "score": light.best.score, "margin": round(light.margin, 3), "told": light.told,
                       "ranking": [[h.env, round(h.score, 6)] for h in light.ranking]},
             "metal": {"evidence": round(evidence, 4), "gated": gated},
             **({"refined": {"candidate_share": round(read.refined.candidate_share, 4),
                             "score": read.refined.score, "start_score": read.refined.start_score}}
                if read.refined is not None else {}),
             "points": len(points), "points_read": len(points) if read.sub is None else len(read.sub),
             "median_views_per_point": float(np.median(read.obs.views_per_point().numpy())),
             "seconds": {"observe": read.seconds["observe"], "light": read.seconds["light"],
                         "readout": round(read.seconds["grid"] + time.perf_counter() - t0, 2)},
             "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()}}
    return pbr, stats


def inference_light_table(points: PointCloud, renders, data_cfg, photos: LatticePhotos | None = None
                          ) -> tuple[tuple[np.ndarray, np.ndarray], dict]:
    """Stage II's ``light_readout`` condition at inference: the light estimated among the model's
    ``stage2.data.light_candidates`` from the views (``photos`` at the lattice cameras when given,
    else the renders) and the cloud's normals, and the read-out's table of the cloud under it
    (``gspi.stage2.light_condition``); plus what was found."""
    from gspi.stage2.light_condition import cloud_normals_of, estimate_scene_light, readout_table

    cams = LatticeCameras.from_renders(renders)
    xyz = points.xyz.astype(np.float64)
    normals = cloud_normals_of(xyz, points.view, cams)
    candidates = candidate_lights(data_cfg.light_candidates, data_cfg.light_env_height)
    tol = float(data_cfg.visibility_tol_pixels)
    images, depth = views_to_read(renders, photos)
    light, est = estimate_scene_light(images, depth, cams, xyz, normals, candidates, tol_pixels=tol)
    table = readout_table(images, depth, cams, xyz, normals, light, tol_pixels=tol,
                          normal_search_deg=data_cfg.light_normal_search_deg,
                          normal_profile=data_cfg.light_normal_profile,
                          metal_min_evidence=data_cfg.light_metal_min_evidence)
    return table, {"env": est.env, "rotation_deg": round(est.rotation_deg, 2), "gain": round(est.gain, 4),
                   "margin": round(est.margin, 3)}
