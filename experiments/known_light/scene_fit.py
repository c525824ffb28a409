"""One scene of a Stage II dataset read by the known-light fit (``gspi.light``): its GT points,
their GT normals (``normal.exr`` at each point's source pixel), the lattice views of a views
folder (the exact renders, or a Stage 0 asset's renders in a ``gspi.recon.reconstructed_pool``
folder) and the capture environment from ``envmaps/``, turned or swapped on request.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from eval.common.colorspace import linear_to_srgb
from eval.common.imageio import read_exr
from eval.common.layout import read_scene, read_view_file
from eval.relight import PrefilteredEnvironment, prefilter_environment
from gspi.gaussians.model import Gaussians2D
from gspi.light.observations import PointViews
from gspi.light.readout import fit_grid, pool_neighbours, read_best, read_posterior
from gspi.point_cloud import nearest_fill
from gspi.stage2.data import ScenePoints, read_lattice_views
from gspi.stage2.light_views import observe_points

MAX_POINTS = 20000   # Table 2's measure: a seeded subset, 1-NN fill
READOUTS = ("map", "knn_post")
SURFELS_PER_POINT = 8  # surfels whose normals (facing the source camera, weighted by opacity) a point takes


@dataclass(frozen=True)
class Light:
    """Which environment the fit is told: the scene's own, turned, or another one."""

    env: str | None = None      # None: the scene's capture_env
    rotation_deg: float = 0.0


def gt_normals(scene_dir: Path, points: ScenePoints) -> np.ndarray:
    """[P, 3] the GT normal at every point's source pixel (``normal.exr`` of the train views)."""
    scene = read_scene(scene_dir)
    maps = np.stack([read_view_file(scene.view_dir("train", v.id), "normal.exr")
                     for v in scene.split_views("train")])
    return maps[points.view, points.pixel[:, 0], points.pixel[:, 1]]


@cache
def prefiltered(path: str) -> PrefilteredEnvironment:
    return prefilter_environment(torch.from_numpy(read_exr(Path(path)).astype(np.float32)))


def env_path(gt_scene_dir: Path, name: str | None) -> Path:
    """An environment's EXR: the scene's own ``envmaps/`` when it has it, else a sibling scene's."""
    scene = read_scene(gt_scene_dir)
    name = name or scene.capture_env
    own = scene.envmap_path(name)
    if own.is_file():
        return own
    for other in sorted(gt_scene_dir.parent.iterdir()):
        p = other / "envmaps" / f"{name}.exr"
        if p.is_file():
            return p
    raise FileNotFoundError(f"{own}: no scene beside {gt_scene_dir} holds environment {name!r}")


def subset(points: ScenePoints, index: int, max_points: int = MAX_POINTS, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng([seed, index])
    if points.num_points <= max_points:
        return np.arange(points.num_points)
    return np.sort(rng.choice(points.num_points, max_points, replace=False))


def observations(points: ScenePoints, keep: np.ndarray, views_dir: Path, normals: np.ndarray) -> PointViews:
    rgb, depth = read_lattice_views(views_dir)
    return observe_points(rgb, depth, points.cameras, points.xyz[keep], normals[keep])


def surfel_normals(asset: Gaussians2D, xyz: np.ndarray, source_center: np.ndarray) -> np.ndarray:
    """[n, 3] unit normals at ``xyz`` [n, 3]: the asset's nearest surfels' normals, each turned to
    face the point's source camera ``source_center`` [n, 3], averaged with opacity weights."""
    means = asset.means.detach().cpu().numpy().astype(np.float64)
    normals = asset.normals.detach().cpu().numpy().astype(np.float64)
    opacity = asset.opacities.detach().cpu().numpy().reshape(-1).astype(np.float64)
    k = min(SURFELS_PER_POINT, len(means))
    _, nn = cKDTree(means).query(xyz, k=k)
    nn = np.asarray(nn).reshape(len(xyz), k)
    nrm = normals[nn]                                          # [n, k, 3]
    facing = np.sign(np.einsum("nkc,nc->nk", nrm, source_center - xyz))
    facing[facing == 0] = 1.0
    mean = (nrm * (facing * opacity[nn])[..., None]).sum(axis=1)
    length = np.linalg.norm(mean, axis=1, keepdims=True)
    return np.where(length > 1e-9, mean / np.maximum(length, 1e-12), source_center - xyz)



def asset_normals(points: ScenePoints, keep: np.ndarray, views_dir: Path) -> np.ndarray:
    """[P, 3] normals of points ``keep`` from the Stage 0 asset of a reconstructed pool's scene
    (``asset/point_cloud.ply``, ``surfel_normals``: the surfel normals the product does not read,
    measured here); zeros elsewhere."""
    from gspi.gaussians.ply import read_ply

    asset = read_ply(views_dir / "asset" / "point_cloud.ply")
    out = np.zeros((points.num_points, 3))
    out[keep] = surfel_normals(asset, points.xyz[keep], points.cameras.centers[points.view[keep]])
    return out


def predict(points: ScenePoints, index: int, gt_dir: Path, views_dir: Path, light: Light = Light(), *,
            temperature: float | None = None, normals: str = "gt") -> dict[str, np.ndarray]:
    """{read-out: [P, 5] PBR (sRGB albedo, roughness, metallic)} of every point of the scene: its GT
    (normals, environments) from ``gt_dir``, the views read from ``views_dir``."""
    keep = subset(points, index)
    nrm = gt_normals(gt_dir, points) if normals == "gt" else asset_normals(points, keep, views_dir)
    obs = observations(points, keep, views_dir, nrm)
    grid = fit_grid(obs, prefiltered(str(env_path(gt_dir, light.env))), rotation_deg=light.rotation_deg)
    pooled = pool_neighbours(grid, obs.xyz)
    kw = {} if temperature is None else {"temperature": temperature}
    out = {}
    for name, (albedo, rough, metal) in (("map", read_best(grid)), ("knn_post", read_posterior(grid, pooled, **kw))):
        pbr = torch.cat([linear_to_srgb(albedo), rough[:, None], metal[:, None]], dim=1).numpy()
        out[name] = nearest_fill(points.xyz[keep], pbr, points.xyz).astype(np.float32)
    return out
