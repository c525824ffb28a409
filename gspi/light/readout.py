"""Each point's material read against a known light: a grid over (roughness, metallic) with the
least-squares albedo in each cell (``fit_grid``), the evidence pooled over a point's nearest
neighbours (``pool_neighbours``), and two read-outs: the best cell (``read_best``) and the
posterior mean of the pooled grid (``read_posterior``).

The error of a cell is the relative residual ``sum_v |c_v - a P_v - Q_v|^2 / sum_v |c_v|^2`` over
the views that see the point (``gspi.light.shading``), with the albedo clamped to [0, 1]; so a
bright and a dark point weigh alike when pooled. Training-free: the light and the views are all
it needs. It is also a method of its own (``method=light_fit``) and Stage II's condition.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from eval.relight import PrefilteredEnvironment
from gspi.light.observations import PointViews
from gspi.light.shading import ViewTerms, affine_coefficients, view_terms

ROUGHNESS_GRID = tuple(k / 20 for k in range(21))  # 0, 0.05, ..., 1
METALLIC_GRID = (0.0, 1.0)
NEIGHBOURS = 16               # points pooled per point (itself included)
POSTERIOR_TEMPERATURE = 0.1   # read_posterior: weight exp(-(e / e_min - 1) / T) of a pooled cell
_EPS = 1e-12


@dataclass(frozen=True)
class MaterialGrid:
    """The evidence of every point for every (roughness, metallic) cell.

    Attributes:
        error: [n, R, K] relative residual of each cell (1.0 for a point no view sees).
        albedo: [n, R, K, 3] linear least-squares albedo of each cell, in [0, 1].
        roughness: [R] the grid's roughness values.
        metallic: [K] the grid's metallic values.
        views: [n] how many views see each point.
    """

    error: Tensor
    albedo: Tensor
    roughness: Tensor
    metallic: Tensor
    views: Tensor

    def best_error(self) -> Tensor:
        """[n] each point's smallest relative residual over the grid."""
        return self.error.flatten(1).min(dim=1).values


def fit_grid(obs: PointViews, pre: PrefilteredEnvironment, *, roughness=ROUGHNESS_GRID,
             metallic=METALLIC_GRID, rotation_deg: float = 0.0, gain: float = 1.0) -> MaterialGrid:
    """The grid fit of every point of ``obs`` under ``pre`` turned by ``rotation_deg`` and scaled
    by ``gain`` (the observed radiance is read as ``gain * shade``)."""
    rough = torch.as_tensor(roughness, dtype=torch.float32)
    terms = view_terms(pre, obs.normal[obs.point], obs.view_dir, rough, rotation_deg=rotation_deg)
    return fit_terms(obs, terms, rough, metallic, gain=gain)


def fit_terms(obs: PointViews, terms: ViewTerms, roughness: Tensor, metallic=METALLIC_GRID, *,
              gain: float = 1.0) -> MaterialGrid:
    """``fit_grid`` from the shader's terms already evaluated at the observations (so a light's
    gains are tried without sampling the environment again)."""
    colour = obs.colour / float(gain)
    n, idx = obs.num_points, obs.point
    energy = _sum_per_point(colour.pow(2).sum(-1), idx, n)                       # [n]
    errors, albedos = [], []
    for m in metallic:
        p, q = affine_coefficients(terms, float(m))                              # [R, M, 3]
        num = _sum_per_point(((colour[None] - q) * p).transpose(0, 1), idx, n)   # [n, R, 3]
        den = _sum_per_point(p.pow(2).transpose(0, 1), idx, n)
        albedo = (num / den.clamp_min(_EPS)).clamp(0.0, 1.0)
        resid = colour[None] - albedo[idx].transpose(0, 1) * p - q               # [R, M, 3]
        err = _sum_per_point(resid.pow(2).sum(-1).transpose(0, 1), idx, n)      # [n, R]
        errors.append(err / energy[:, None].clamp_min(_EPS))
        albedos.append(albedo)
    views = torch.bincount(idx, minlength=n)
    error = torch.stack(errors, dim=2)
    error[views == 0] = 1.0
    return MaterialGrid(error=error, albedo=torch.stack(albedos, dim=2), roughness=roughness,
                        metallic=torch.as_tensor(metallic, dtype=torch.float32), views=views)


def _sum_per_point(values: Tensor, index: Tensor, n: int) -> Tensor:
    """Rows of ``values`` [M, ...] summed per point ``index`` [M] -> [n, ...]."""
    out = torch.zeros((n, *values.shape[1:]), dtype=values.dtype)
    return out.index_add_(0, index, values)


def pool_neighbours(grid: MaterialGrid, xyz: Tensor | np.ndarray, k: int = NEIGHBOURS) -> Tensor:
    """[n, R, K] each point's error grid averaged over its ``k`` nearest points (itself included)
    that some view sees; a point no view sees takes its observed neighbours' mean."""
    xyz = np.asarray(xyz, dtype=np.float64)
    seen = (grid.views > 0).numpy()
    if not seen.any():
        return grid.error.clone()
    source = np.flatnonzero(seen)
    k = min(k, len(source))
    _, nn = cKDTree(xyz[source]).query(xyz, k=k)
    nn = source[np.asarray(nn).reshape(len(xyz), k)]
    return grid.error[torch.from_numpy(nn)].mean(dim=1)


def read_best(grid: MaterialGrid) -> tuple[Tensor, Tensor, Tensor]:
    """(linear albedo [n, 3], roughness [n], metallic [n]) of each point's best cell."""
    n, r, k = grid.error.shape
    best = grid.error.flatten(1).argmin(dim=1)
    ri, mi = best // k, best % k
    rows = torch.arange(n)
    return grid.albedo[rows, ri, mi], grid.roughness[ri], grid.metallic[mi]


def posterior(error: Tensor, temperature: float = POSTERIOR_TEMPERATURE) -> Tensor:
    """[n, R, K] weights summing to 1 per point: ``exp(-(e / e_min - 1) / T)``, normalised (scale
    free: a grid and the same grid times a constant give one posterior)."""
    flat = error.flatten(1)
    e_min = flat.min(dim=1, keepdim=True).values.clamp_min(_EPS)
    w = torch.softmax(-(flat / e_min - 1.0) / temperature, dim=1)
    return w.reshape(error.shape)


def read_posterior(grid: MaterialGrid, pooled_error: Tensor, temperature: float = POSTERIOR_TEMPERATURE
                   ) -> tuple[Tensor, Tensor, Tensor]:
    """(linear albedo [n, 3], roughness [n], metallic [n]): means under the posterior of the
    pooled grid; the albedo is the point's own least-squares albedo averaged with those weights."""
    w = posterior(pooled_error, temperature)
    rough = (w.sum(dim=2) * grid.roughness).sum(dim=1)
    metal = (w.sum(dim=1) * grid.metallic).sum(dim=1)
    albedo = (w[..., None] * grid.albedo).sum(dim=(1, 2))
    return albedo, rough, metal
