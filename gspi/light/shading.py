"""The split-sum shader (``eval.relight.split_sum``) as an affine map of the linear albedo.

For fixed roughness r and metallic m, with ``S = S(R, r)`` the prefiltered environment in the
mirror direction, (A, B) the DFG terms at (n.v, r) and E(n) the irradiance::

    c = albedo * P + Q,   P = (1 - m) E(n) / pi + m S A,   Q = S (0.04 (1 - m) A + B)

per channel. ``view_terms`` evaluates E, S, A, B once per roughness of a grid (they do not
depend on m or the albedo); ``affine_coefficients`` forms (P, Q) for any metallic value. The
identity is tested against ``split_sum`` itself (tests/test_light.py).

An environment turned by ``rotation_deg`` about the up axis (+z) is read as the unturned map at
the directions turned back: ``L_psi(d) = L(Rz(-psi) d)`` (``turn_directions``). Rolling a
lat-long map by k columns turns it by ``psi = -360 k / W`` (``rotate_latlong``).
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import torch
from torch import Tensor

from eval.brdf_lut import lookup_dfg
from eval.envmap import bilinear_latlong, direction_to_pixel
from eval.relight import PrefilteredEnvironment

DIELECTRIC_F0 = 0.04  # the shader's F0 of a dielectric (eval.relight)


@dataclass(frozen=True)
class ViewTerms:
    """The shader's terms at every observation for each roughness of a grid.

    Attributes:
        diffuse: [M, 3] E(n) / pi.
        specular: [R, M, 3] S(R, r_k).
        dfg_a, dfg_b: [R, M] the DFG terms at (n.v, r_k).
    """

    diffuse: Tensor
    specular: Tensor
    dfg_a: Tensor
    dfg_b: Tensor


def turn_directions(d: Tensor, rotation_deg: float) -> Tensor:
    """[..., 3] directions turned by -rotation_deg about +z (where a turned map is read)."""
    if rotation_deg == 0:
        return d
    a = math.radians(-rotation_deg)
    c, s = math.cos(a), math.sin(a)
    x, y, z = d.unbind(-1)
    return torch.stack([c * x - s * y, s * x + c * y, z], dim=-1)


def rotate_latlong(envmap: Tensor, columns: int) -> Tensor:
    """The lat-long map turned by ``-360 * columns / W`` degrees about +z (a roll of its columns)."""
    return torch.roll(envmap, shifts=int(columns), dims=1)


class _LatLongSampler:
    """Bilinear lookups of lat-long maps of any size at one set of directions, the angles computed
    once (``eval.envmap.sample_latlong`` recomputes them per call; a grid fit reads ~20 maps at the
    same directions); the lookup itself is ``eval.envmap.bilinear_latlong``, sample_latlong's own."""

    def __init__(self, directions: Tensor):
        row1, col1 = direction_to_pixel(directions.to(torch.float32), 1, 1)  # the map-size-free coordinates
        self.row_frac, self.col_frac = row1 + 0.5, col1 + 0.5

    def __call__(self, envmap: Tensor) -> Tensor:
        h, w, _ = envmap.shape
        return bilinear_latlong(envmap, self.row_frac * h - 0.5, self.col_frac * w - 0.5)


def _specular_at(pre: PrefilteredEnvironment, level, roughness: float) -> Tensor:
    """``eval.relight``'s specular lookup at one roughness: its two bracketing levels (``level(k)``:
    level k sampled at the directions), interpolated."""
    levels = pre.level_roughness
    k = min(max(bisect_right(levels, roughness) - 1, 0), len(levels) - 2)
    t = min(max((roughness - levels[k]) / (levels[k + 1] - levels[k]), 0.0), 1.0)
    if t == 0.0:
        return level(k)
    if t == 1.0:
        return level(k + 1)
    return (1 - t) * level(k) + t * level(k + 1)


def _clamped(roughness: Tensor) -> list[float]:
    return [min(max(float(r), 0.0), 1.0) for r in roughness.tolist()]


def view_dfg(pre: PrefilteredEnvironment, normal: Tensor, view_dir: Tensor, roughness: Tensor) -> tuple[Tensor, Tensor]:
    """(A, B), each [R, M]: the DFG terms at (n.v, r) of the observations for each roughness. They
    depend on neither the light nor its turn (n.v is the same turned), so a light search over turns
    computes them once."""
    n_dot_v = (normal * view_dir).sum(-1).clamp(1e-4, 1.0)
    rough = _clamped(roughness)
    grid = torch.tensor(rough, dtype=n_dot_v.dtype)[:, None].expand(len(rough), len(n_dot_v))
    return lookup_dfg(pre.lut, n_dot_v[None].expand_as(grid), grid)


def view_terms(pre: PrefilteredEnvironment, normal: Tensor, view_dir: Tensor, roughness: Tensor, *,
               rotation_deg: float = 0.0, dfg: tuple[Tensor, Tensor] | None = None) -> ViewTerms:
    """E, S, A, B at observations with unit ``normal`` and ``view_dir`` [M, 3] (surface -> camera),
    for each roughness of ``roughness`` [R], under ``pre`` turned by ``rotation_deg``; ``dfg``: the
    observations' ``view_dfg`` when already computed."""
    n = turn_directions(normal, rotation_deg)
    wo = turn_directions(view_dir, rotation_deg)
    n_dot_wo = (n * wo).sum(-1, keepdim=True)
    refl = 2 * n_dot_wo * n - wo
    diffuse = _LatLongSampler(n)(pre.irradiance) / math.pi
    at_refl = _LatLongSampler(refl)
    sampled: dict[int, Tensor] = {}  # each level read once, though several roughness values bracket it

    def level(k: int) -> Tensor:
        if k not in sampled:
            sampled[k] = at_refl(pre.specular[k])
        return sampled[k]

    spec = torch.stack([_specular_at(pre, level, r) for r in _clamped(roughness)])
    dfg_a, dfg_b = dfg if dfg is not None else view_dfg(pre, normal, view_dir, roughness)
    return ViewTerms(diffuse=diffuse, specular=spec, dfg_a=dfg_a, dfg_b=dfg_b)


def affine_coefficients(terms: ViewTerms, metallic: float) -> tuple[Tensor, Tensor]:
    """(P, Q), each [R, M, 3]: the shaded radiance is ``albedo * P + Q`` at every roughness."""
    a, b = terms.dfg_a[..., None], terms.dfg_b[..., None]
    p = (1 - metallic) * terms.diffuse[None] + metallic * terms.specular * a
    q = terms.specular * (DIELECTRIC_F0 * (1 - metallic) * a + b)
    return p, q
