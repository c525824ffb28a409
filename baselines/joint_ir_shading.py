"""Differentiable split-sum shading with a learnable low-resolution environment.

The joint inverse-rendering baseline (``baselines/joint_ir.py``) learns the lighting as
a small lat-long map. Every prefiltered quantity of ``eval.relight`` (the irradiance map
and the GGX-prefiltered specular levels) is a LINEAR function of the environment: an
area-weighted downsampling (``eval.envmap.downsample_latlong``) followed by a normalised
zonal filter (``eval.envmap.zonal_filter``). So for one resolution ``h x w`` each of them is
a fixed matrix ``[out_pixels, h * w]``, built here once (and kept in an in-process cache)
by pushing the identity basis through the very functions ``eval.relight`` uses (three
basis texels at a time, as the three colour channels of one map: those functions take
``[H, W, 3]`` maps). Applying the matrices to the learnable map gives a
:class:`eval.relight.PrefilteredEnvironment` whose tensors carry gradients, and
:func:`eval.relight.split_sum` (the evaluator's own shader, differentiable in all its
inputs) shades with it. Conventions, level resolutions and the DFG table are therefore
those of the evaluator by construction; ``tests/test_baselines_inhouse.py`` checks that
the result equals ``split_sum`` called with the raw map.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from eval.brdf_lut import dfg_lut
from eval.envmap import downsample_latlong
from eval.relight import (DEFAULT_LEVEL_ROUGHNESS, PrefilteredEnvironment, ggx_prefilter,
                          irradiance_map, level_factor, split_sum)

__all__ = ["PrefilterOperators", "prefilter_operators", "prefilter_learnable", "shade"]


@dataclass(frozen=True)
class PrefilterOperators:
    """Linear maps from a ``[h, w, 3]`` environment to its prefiltered levels.

    Attributes:
        height, width: Resolution of the environment the operators apply to.
        irradiance: ``[He * We, h * w]`` matrix and its output grid ``(He, We)``.
        specular: Per roughness level ``k >= 1``, a ``[Hk * Wk, h * w]`` matrix (level 0
            is the map itself) and the level's grid.
        level_roughness: Roughness of each level (``eval.relight.DEFAULT_LEVEL_ROUGHNESS``).
        lut: ``[S, S, 2]`` DFG table (``eval.brdf_lut.dfg_lut`` at the evaluator's defaults).
    """

    height: int
    width: int
    irradiance: tuple[Tensor, tuple[int, int]]
    specular: tuple[tuple[Tensor, tuple[int, int]], ...]
    level_roughness: tuple[float, ...]
    lut: Tensor

    def to(self, device) -> "PrefilterOperators":
        """The same operators with every matrix on ``device`` (no copy where already there), so
        that :func:`prefilter_learnable` does not copy them at every step."""
        def move(op: tuple[Tensor, tuple[int, int]]) -> tuple[Tensor, tuple[int, int]]:
            return op[0].to(device), op[1]
        return replace(self, irradiance=move(self.irradiance),
                       specular=tuple(move(op) for op in self.specular), lut=self.lut.to(device))


def _operator_matrix(height: int, width: int, fn) -> tuple[Tensor, tuple[int, int]]:
    """Matrix of a linear map ``fn: [h, w, 3] -> [Ho, Wo, 3]`` acting on each channel alike.

    Column ``k`` is ``fn`` of the map that is 1 at texel ``k`` and 0 elsewhere; the basis
    goes through ``fn`` three texels at a time (one per colour channel).

    Returns:
        ``[Ho * Wo, h * w]`` float32 matrix and the output grid ``(Ho, Wo)``.
    """
    n = height * width
    columns = []
    for start in range(0, n, 3):
        ids = torch.arange(start, min(start + 3, n))
        basis = torch.zeros(n, 3)
        basis[ids, torch.arange(len(ids))] = 1.0
        out = fn(basis.reshape(height, width, 3))
        columns.append(out.reshape(-1, 3)[:, :len(ids)])
    return torch.cat(columns, dim=1).contiguous(), tuple(out.shape[:2])


@functools.lru_cache(maxsize=4)
def prefilter_operators(height: int, width: int, *, max_level_height: int = 256,
                        min_level_height: int = 16, irradiance_height: int = 64,
                        lut_size: int = 128, lut_samples: int = 1024) -> PrefilterOperators:
    """Operators reproducing ``eval.relight.prefilter_environment`` at its defaults.

    Same steps, in the same order, as ``prefilter_environment``: per level ``r > 0`` the
    map is area-downsampled to the fewest rows >= ``clamp(pi / r^2, min, max)`` and
    GGX-filtered; the irradiance uses ~``irradiance_height`` rows. Cached per arguments.

    Args:
        height, width: Environment resolution ``h x w`` (``w = 2 h`` by the format).

    Returns:
        :class:`PrefilterOperators` (CPU float32; memory ~ levels x (h w)^2 floats: 12 MB
        and ~1.5 s to build at 16 x 32, ~140 MB and ~15 s at 32 x 64).
    """
    if height < 1 or width < 1:
        raise ValueError(f"environment resolution must be positive, got {height}x{width}")
    irr = _operator_matrix(height, width, lambda env: irradiance_map(env, irradiance_height))
    levels = tuple(float(r) for r in DEFAULT_LEVEL_ROUGHNESS)
    specular = []
    for r in levels[1:]:
        target = min(max(math.pi / r ** 2, min_level_height), max_level_height)
        factor = level_factor(height, width, target)
        specular.append(_operator_matrix(
            height, width, lambda env, f=factor, r=r: ggx_prefilter(downsample_latlong(env, f), r)))
    return PrefilterOperators(height, width, irr, tuple(specular), levels,
                              dfg_lut(lut_size, lut_samples))


def prefilter_learnable(envmap: Tensor, ops: PrefilterOperators) -> PrefilteredEnvironment:
    """Prefiltered environment of a (learnable) map, differentiable w.r.t. ``envmap``.

    Args:
        envmap: ``[h, w, 3]`` linear HDR radiance, lat-long (docs/FORMAT.md convention).
        ops: Operators for ``h x w`` (:func:`prefilter_operators`).

    Returns:
        :class:`eval.relight.PrefilteredEnvironment` whose maps depend on ``envmap``.
    """
    if envmap.shape != (ops.height, ops.width, 3):
        raise ValueError(f"envmap must be [{ops.height}, {ops.width}, 3], got {tuple(envmap.shape)}")
    flat = envmap.reshape(-1, 3)

    def apply(op: tuple[Tensor, tuple[int, int]]) -> Tensor:
        matrix, (ho, wo) = op
        return (matrix.to(flat) @ flat).reshape(ho, wo, 3)

    levels = (envmap,) + tuple(apply(op) for op in ops.specular)
    return PrefilteredEnvironment(apply(ops.irradiance), levels, ops.level_roughness,
                                  ops.lut.to(envmap.device))


def shade(albedo_linear: Tensor, roughness: Tensor, metallic: Tensor, normal: Tensor,
          view_dir: Tensor, envmap: Tensor, ops: PrefilterOperators | None = None) -> Tensor:
    """Split-sum radiance of pixels under a learnable environment (``eval.relight.split_sum``).

    Args:
        albedo_linear: ``[..., 3]`` linear base colour in [0, 1].
        roughness, metallic: ``[..., 1]`` in [0, 1].
        normal: ``[..., 3]`` unit world normals.
        view_dir: ``[..., 3]`` unit vectors surface -> camera.
        envmap: ``[h, w, 3]`` linear HDR lat-long map (may require grad).
        ops: Operators for the map's resolution (looked up in the cache when None).

    Returns:
        ``[..., 3]`` linear radiance, differentiable w.r.t. every input.
    """
    if ops is None:
        ops = prefilter_operators(envmap.shape[0], envmap.shape[1])
    pre = prefilter_learnable(envmap, ops)
    return split_sum(albedo_linear, roughness, metallic, normal, view_dir, pre)
