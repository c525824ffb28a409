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

import math
from dataclasses import dataclass, replace

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

    def mean_best_error(self) -> float:
        """The mean of ``best_error`` over the points some view sees: how well the light explains the
        views (``gspi.light.estimate``'s score)."""
        return float(self.best_error()[self.views > 0].mean())


def fit_grid(obs: PointViews, pre: PrefilteredEnvironment, *, roughness=ROUGHNESS_GRID,
             metallic=METALLIC_GRID, rotation_deg: float = 0.0, gain: float = 1.0) -> MaterialGrid:
    """The grid fit of every point of ``obs`` under ``pre`` turned by ``rotation_deg`` and scaled
    by ``gain`` (the observed radiance is read as ``gain * shade``)."""
    rough = torch.as_tensor(roughness, dtype=torch.float32)
    terms = view_terms(pre, obs.normal[obs.point], obs.view_dir, rough, rotation_deg=rotation_deg)
    return fit_terms(obs, terms, rough, metallic, gain=gain)


def cone_normals(normal: Tensor, rings_deg=(), per_ring: int = 6) -> Tensor:
    """[C, n, 3] candidate unit normals around each ``normal`` [n, 3]: the normal itself, then
    ``per_ring`` directions at each angle of ``rings_deg`` (degrees) around it, evenly turned."""
    n = torch.nn.functional.normalize(normal.float(), dim=-1)
    helper = torch.where((n[:, :1].abs() < 0.9), torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]))
    t1 = torch.nn.functional.normalize(torch.cross(helper, n, dim=-1), dim=-1)
    t2 = torch.cross(n, t1, dim=-1)
    out = [n]
    for ring, theta in enumerate(rings_deg):
        th = math.radians(float(theta))
        for j in range(per_ring):
            phi = 2 * math.pi * (j + 0.5 * (ring % 2)) / per_ring  # alternate rings offset by half a step
            out.append(math.cos(th) * n + math.sin(th) * (math.cos(phi) * t1 + math.sin(phi) * t2))
    return torch.stack(out)


SEARCH_ROUGHNESS = (0.0, 0.1, 0.2, 0.35, 0.5, 0.75, 1.0)  # refine_normals' coarse grid


def rank_normals(obs: PointViews, pre: PrefilteredEnvironment, *, rings_deg=(4.0, 8.0), per_ring: int = 6,
                 roughness=SEARCH_ROUGHNESS, metallic=METALLIC_GRID, rotation_deg: float = 0.0,
                 gain: float = 1.0) -> tuple[Tensor, Tensor]:
    """The ``cone_normals`` around each point's given normal [C, n, 3] and, per point, the
    candidates' order [C, n] by the error of their best cell of a coarse grid (best first; on a
    tie the earlier candidate, so a point no view sees keeps its normal first)."""
    candidates = cone_normals(obs.normal, rings_deg, per_ring)  # [C, n, 3]
    errors = torch.stack([fit_grid(replace(obs, normal=normal), pre, roughness=roughness, metallic=metallic,
                                   rotation_deg=rotation_deg, gain=gain).best_error() for normal in candidates])
    return candidates, torch.sort(errors, dim=0, stable=True).indices


def refine_normals(obs: PointViews, pre: PrefilteredEnvironment, *, rings_deg=(4.0, 8.0), per_ring: int = 6,
                   roughness=SEARCH_ROUGHNESS, metallic=METALLIC_GRID, rotation_deg: float = 0.0,
                   gain: float = 1.0) -> Tensor:
    """[n, 3] each point's normal among ``cone_normals`` around its given one: the candidate whose
    best cell of a coarse grid fits the views with the smallest error, as photometric stereo
    refines a normal (on a tie the earlier candidate, so a point no view sees keeps its normal).
    For normals a few degrees off (a reconstructed asset's cloud), whose mirror directions miss a
    sharp light's highlights."""
    candidates, order = rank_normals(obs, pre, rings_deg=rings_deg, per_ring=per_ring, roughness=roughness,
                                     metallic=metallic, rotation_deg=rotation_deg, gain=gain)
    return candidates[order[0], torch.arange(obs.num_points)]


def min_over_normals(grids: list[MaterialGrid]) -> MaterialGrid:
    """The grid whose every cell is the best of ``grids`` (the same points read at different
    normals): a profile over the normal, each cell's error its smallest and its albedo that fit's."""
    error = torch.stack([g.error for g in grids])  # [k, n, R, K]
    best = error.argmin(dim=0)
    albedo = torch.stack([g.albedo for g in grids]).gather(0, best[None, ..., None].expand(1, *grids[0].albedo.shape))[0]
    return replace(grids[0], error=error.gather(0, best[None])[0], albedo=albedo)


def fit_grid_normal_search(obs: PointViews, pre: PrefilteredEnvironment, *, rings_deg=(4.0, 8.0), per_ring: int = 6,
                           profile: int = 1, roughness=ROUGHNESS_GRID, metallic=METALLIC_GRID,
                           rotation_deg: float = 0.0, gain: float = 1.0) -> MaterialGrid:
    """``fit_grid`` at each point's normal refined by :func:`refine_normals`; with ``profile`` k > 1
    the grid fitted at each of the k candidates a coarse grid ranks best, every cell taking the
    best of them (:func:`min_over_normals`): a cell (a glossy metal, say) then need not share the
    normal that suits another (a rough dielectric). k = 1 is the single refined normal; each more
    costs one full grid fit."""
    if profile < 1:
        raise ValueError(f"profile={profile}: the number of normals profiled must be >= 1")
    candidates, order = rank_normals(obs, pre, rings_deg=rings_deg, per_ring=per_ring, metallic=metallic,
                                     rotation_deg=rotation_deg, gain=gain)
    points = torch.arange(obs.num_points)
    grids = [fit_grid(replace(obs, normal=candidates[order[j], points]), pre, roughness=roughness,
                      metallic=metallic, rotation_deg=rotation_deg, gain=gain)
             for j in range(min(profile, len(candidates)))]
    return grids[0] if len(grids) == 1 else min_over_normals(grids)


@dataclass(frozen=True)
class GridSums:
    """Per point, per cell and channel, the sums over its views that fix the least-squares albedo
    and the residual at any gain g (observations read as c / g): with P, Q the affine terms,
    ``a = (cP / g - QP) / PP`` and ``|c/g - aP - Q|^2 = cc/g^2 + a^2 PP + QQ - 2a cP/g - 2 cQ/g + 2a QP``.
    Trying a gain then costs no pass over the observations. float64: the expansion cancels."""

    cc: Tensor   # [n] sum of |c|^2 over channels
    cp: Tensor   # [n, R, K, 3] sum c P
    cq: Tensor   # [n, R, K, 3] sum c Q
    pp: Tensor   # [n, R, K, 3] sum P^2
    qq: Tensor   # [n, R, K, 3] sum Q^2
    qp: Tensor   # [n, R, K, 3] sum Q P
    views: Tensor
    roughness: Tensor
    metallic: Tensor


def grid_sums(obs: PointViews, terms: ViewTerms, roughness: Tensor, metallic=METALLIC_GRID) -> GridSums:
    """The sums of ``GridSums`` from the shader's terms at the observations."""
    n, idx = obs.num_points, obs.point
    c = obs.colour.double()
    parts: dict[str, list[Tensor]] = {k: [] for k in ("cp", "cq", "pp", "qq", "qp")}
    for m in metallic:
        p, q = (t.double().transpose(0, 1) for t in affine_coefficients(terms, float(m)))  # [M, R, 3]
        for key, value in (("cp", c[:, None] * p), ("cq", c[:, None] * q), ("pp", p * p), ("qq", q * q),
                           ("qp", q * p)):
            parts[key].append(_sum_per_point(value, idx, n))
    stacked = {k: torch.stack(v, dim=2) for k, v in parts.items()}   # [n, R, K, 3]
    return GridSums(cc=_sum_per_point(c.pow(2).sum(-1), idx, n), views=torch.bincount(idx, minlength=n),
                    roughness=roughness, metallic=torch.as_tensor(metallic, dtype=torch.float32), **stacked)


def grid_at_gain(sums: GridSums, gain: float = 1.0) -> MaterialGrid:
    """The ``MaterialGrid`` of the observations read as ``gain * shade``."""
    inv = 1.0 / float(gain)
    albedo = ((sums.cp * inv - sums.qp) / sums.pp.clamp_min(_EPS)).clamp(0.0, 1.0)
    resid = (sums.cc[:, None, None, None] / 3 * inv * inv + albedo.pow(2) * sums.pp + sums.qq
             - 2 * albedo * sums.cp * inv - 2 * sums.cq * inv + 2 * albedo * sums.qp).sum(-1).clamp_min(0.0)
    energy = (sums.cc * inv * inv).clamp_min(_EPS)
    error = (resid / energy[:, None, None]).float()
    error[sums.views == 0] = 1.0
    return MaterialGrid(error=error, albedo=albedo.float(), roughness=sums.roughness, metallic=sums.metallic,
                        views=sums.views)


def fit_terms(obs: PointViews, terms: ViewTerms, roughness: Tensor, metallic=METALLIC_GRID, *,
              gain: float = 1.0) -> MaterialGrid:
    """``fit_grid`` from the shader's terms already evaluated at the observations."""
    return grid_at_gain(grid_sums(obs, terms, roughness, metallic), gain)


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


def metal_evidence(pooled_error: Tensor, metallic: Tensor, seen: Tensor) -> float:
    """How much better the object is explained with metal allowed than without: over the points
    some view sees, the mean of each point's best pooled error among the dielectric cells (m = 0)
    over the mean of its best among all cells (>= 1; 1 when no metal cell is any point's best).
    A scene-level test, since a dielectric point often fits a metal cell nearly as well (a
    posterior that leaks a little metal everywhere); nan when no point is seen."""
    if not bool(seen.any()):
        return float("nan")
    pooled = pooled_error[seen]
    dielectric = pooled[..., metallic == 0].flatten(1).min(dim=1).values
    best = pooled.flatten(1).min(dim=1).values
    return float(dielectric.mean() / best.mean().clamp_min(_EPS))


def metal_ruled_out(evidence: float, min_evidence: float | None) -> bool:
    """The scene-level metal test (``method.metal_min_evidence``, ``stage2.data.light_metal_min_evidence``):
    whether every metal cell is ruled out because allowing metal explains the object less than
    ``min_evidence`` times better than dielectric alone (``metal_evidence``; nan, no point seen:
    ruled out). None: never (each point read on its own)."""
    return min_evidence is not None and not evidence >= min_evidence


def without_metal(pooled_error: Tensor, metallic: Tensor) -> Tensor:
    """The pooled grid with every metal cell (m > 0) ruled out: its posterior puts no weight there."""
    out = pooled_error.clone()
    out[..., metallic > 0] = float("inf")
    return out


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
