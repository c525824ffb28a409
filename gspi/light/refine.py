"""A light in no candidate set (issue 66, item 2b): the best candidate refined by a coarse
environment fitted to the views.

The split-sum radiance is linear in the environment map L: the irradiance E and every prefiltered
level S are linear filters of L (``eval.relight.prefilter_environment``; tested). With each point's
material held fixed (its best cell of ``gspi.light.readout.fit_grid``: linear albedo a, roughness
r, metallic m), every observation is therefore a linear function of L,

    c = sum_k w_k [a ((1 - m) E_k(n) / pi + m S_k(R, r) A) + S_k(R, r) (0.04 (1 - m) A + B)],

over a basis of maps: the candidate's own map (turned as estimated) and ``BASIS_ROWS`` x
2 ``BASIS_ROWS`` box cells of a lat-long grid in the candidate's turned frame. The weights are fitted
per channel by non-negative least squares (``scipy.optimize.nnls``: L stays a light), the materials
re-read under the new map, and so on for ``ROUNDS``. The candidate keeps what the coarse cells
cannot hold (a sun, a window's edge); the cells move light where the candidate has the wrong
sky, ground or colour. The refined map is kept only if it explains the views better (the
estimate's score: the mean over points of the best cell's relative residual).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import nnls
from torch import Tensor

from eval.relight import PrefilteredEnvironment, prefilter_environment
from gspi.light.observations import PointViews
from gspi.light.readout import ROUGHNESS_GRID, fit_grid, read_best
from gspi.light.shading import DIELECTRIC_F0, view_dfg, view_terms

BASIS_ROWS = 4   # the coarse cells: 4 x 8 over the sphere
ROUNDS = 2       # fit the light, re-read the materials, fit again


@dataclass(frozen=True)
class RefinedLight:
    """A light fitted to the views: its map's prefiltered form (read turned by ``rotation_deg``, gain 1)."""

    pre: PrefilteredEnvironment
    envmap: Tensor              # [H, W, 3] the map in the candidate's frame
    rotation_deg: float
    candidate_share: float      # the candidate's share of the map's mean radiance
    score: float                # mean best relative residual under the refined map
    start_score: float          # ... under the candidate it started from


def candidate_map(pre: PrefilteredEnvironment, gain: float) -> Tensor:
    """[H, W, 3] the candidate's raw map (its level 0) scaled by ``gain``. Its turn stays with the
    reader (every basis map is read turned by the estimate's angle), so the map is not resampled."""
    return pre.specular[0] * float(gain)


def cell_maps(height: int, width: int, rows: int = BASIS_ROWS) -> list[Tensor]:
    """The coarse basis: ``rows`` x 2 ``rows`` box cells of a [height, width] lat-long map, each
    [height, width, 3] (grey: one map serves the three channels)."""
    cols = 2 * rows
    r_edges = np.linspace(0, height, rows + 1).round().astype(int)
    c_edges = np.linspace(0, width, cols + 1).round().astype(int)
    out = []
    for i in range(rows):
        for j in range(cols):
            cell = torch.zeros(height, width, 3)
            cell[r_edges[i]:r_edges[i + 1], c_edges[j]:c_edges[j + 1]] = 1.0
            out.append(cell)
    return out


def design(obs: PointViews, basis: list[PrefilteredEnvironment], albedo: Tensor, rough: Tensor, metal: Tensor,
           rotation_deg: float) -> Tensor:
    """[M, K, 3] each observation's radiance under each basis map (weight 1) with its point's material
    (``albedo`` [n, 3] linear, ``rough`` [n] on ``ROUGHNESS_GRID``, ``metal`` [n])."""
    grid = torch.tensor(ROUGHNESS_GRID, dtype=torch.float32)
    r_index = torch.bucketize(rough.clamp(0, 1), grid).clamp(max=len(grid) - 1)
    p = obs.point
    rows = torch.arange(len(p))
    normal = obs.normal[p]
    a_dfg, b_dfg = view_dfg(basis[0], normal, obs.view_dir, grid)
    a_j, b_j = a_dfg[r_index[p], rows][:, None], b_dfg[r_index[p], rows][:, None]   # [M, 1]
    m_j, alb_j = metal[p][:, None], albedo[p]                                         # [M, 1], [M, 3]
    columns = []
    for pre in basis:
        terms = view_terms(pre, normal, obs.view_dir, grid, rotation_deg=rotation_deg, dfg=(a_dfg, b_dfg))
        spec = terms.specular[r_index[p], rows]                                       # [M, 3]
        columns.append(alb_j * ((1 - m_j) * terms.diffuse + m_j * spec * a_j)
                       + spec * (DIELECTRIC_F0 * (1 - m_j) * a_j + b_j))
    return torch.stack(columns, dim=1)


def fit_weights(phi: Tensor, colour: Tensor) -> np.ndarray:
    """[K, 3] non-negative weights per channel minimising |phi w - colour|^2 (phi [M, K, 3])."""
    phi64, c64 = phi.double().numpy(), colour.double().numpy()
    return np.stack([nnls(phi64[:, :, ch], c64[:, ch], maxiter=50 * phi64.shape[1])[0] for ch in range(3)], axis=1)


def refine_light(obs: PointViews, candidate: PrefilteredEnvironment, rotation_deg: float, gain: float, *,
                 rows: int = BASIS_ROWS, rounds: int = ROUNDS) -> RefinedLight:
    """The candidate ``candidate`` (turned by ``rotation_deg``, scaled by ``gain``, as
    ``gspi.light.estimate`` found it) refined by a coarse environment fitted to ``obs``; the
    candidate itself (``candidate_share`` 1) when no refinement explains the views better."""
    if rounds < 1:
        raise ValueError(f"refine_light needs at least one round, got {rounds}")
    seen = obs.views_per_point() > 0
    if not bool(seen.any()):
        raise ValueError("no view sees any point: the light cannot be refined")
    start = candidate_map(candidate, gain)
    height, width = start.shape[:2]
    basis_maps = torch.stack([start, *cell_maps(height, width, rows)])              # [K, H, W, 3]
    basis = [candidate, *(prefilter_environment(m) for m in basis_maps[1:])]
    grid = fit_grid(obs, candidate, rotation_deg=rotation_deg, gain=gain)          # the materials each round reads
    start_score = grid.mean_best_error()
    pre, envmap, score, share = candidate, start, start_score, 1.0
    for _ in range(rounds):
        albedo, rough, metal = read_best(grid)
        phi = design(obs, basis, albedo, rough, metal, rotation_deg)
        phi[:, 0] *= float(gain)   # the candidate's column at its estimated gain (basis[0] is unscaled)
        weights = torch.from_numpy(fit_weights(phi, obs.colour)).float()   # [K, 3]
        new_map = (basis_maps * weights[:, None, None, :]).sum(0)
        if not bool((new_map > 0).any()):
            break
        new_pre = prefilter_environment(new_map)
        new_grid = fit_grid(obs, new_pre, rotation_deg=rotation_deg)
        new_score = new_grid.mean_best_error()
        if new_score >= score:
            break
        cand_part = (basis_maps[0] * weights[0][None, None, :]).mean()
        pre, envmap, score, share = new_pre, new_map, new_score, float(cand_part / new_map.mean().clamp_min(1e-12))
        grid = new_grid
    return RefinedLight(pre=pre, envmap=envmap, rotation_deg=rotation_deg, candidate_share=share, score=score,
                        start_score=start_score)

