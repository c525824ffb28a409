"""Split-sum image-based lighting in pure torch (nvdiffrec's formula, Z-up lat-long maps).

The shader renders both the benchmark ground truth and every method's relit
predictions (with ground-truth normals), so it is deliberately simple and
deterministic. Per pixel, with ``wo`` = ``view_dir`` (surface -> camera)::

    NdotV    = clamp(n.wo, 1e-4, 1);   R = 2 (n.wo) n - wo
    F0       = 0.04 (1 - m) + albedo m
    diffuse  = albedo (1 - m) E(n) / pi
    specular = S(R, roughness) (F0 A + B),  (A, B) = DFG(NdotV, roughness)

Prefiltering (:func:`prefilter_environment`), all on the lat-long convention
of :mod:`eval.envmap` and all exact brute-force sums over every texel
(evaluated with an azimuthal FFT, see :func:`eval.envmap.zonal_filter`):

* Irradiance ``E(n) = pi * sum L(w) max(n.w,0) dO / sum max(n.w,0) dO`` on the
  environment area-averaged to ~``irradiance_height`` rows (64 by default);
  the normalisation makes constant maps exact (``E = pi L``).
* Specular levels at ``level_roughness`` (default 0, 0.1, ..., 1.0). Level 0
  is the environment itself (mirror). Level ``k > 0`` uses GGX with
  ``alpha = r^2`` and the N=V=R assumption, nvdiffrec's weighting:
  ``S(R) = sum L(w) D(h) max(w.R,0) dO / sum D(h) max(w.R,0) dO``,
  ``h = normalize(w + R)`` (so ``R.h = sqrt((1 + w.R) / 2)``), over the whole
  sphere (no cone cut). A level is computed on the environment area-averaged
  to the fewest rows ``H / f`` (``f`` dividing ``H`` and ``W``) that is at
  least ``clamp(pi / alpha, min_level_height, max_level_height)`` rows
  (texel ~ alpha radians), so resolution decreases with roughness. With the
  defaults a 256x512 map gives rows 256, 256, 128, 64, 32, 16, ..., 16
  (a 128-row map: 128, 128, 128, 64, 32, 16, ...).
* Shading interpolates linearly in roughness between the two bracketing levels.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import math

import torch

from eval.brdf_lut import dfg_lut, lookup_dfg
from eval.envmap import downsample_latlong, sample_latlong, zonal_filter

__all__ = [
    "DEFAULT_LEVEL_ROUGHNESS",
    "PrefilteredEnvironment",
    "level_factor",
    "irradiance_map",
    "ggx_prefilter",
    "prefilter_environment",
    "split_sum",
    "clear_prefilter_cache",
]

DEFAULT_LEVEL_ROUGHNESS = tuple(i / 10 for i in range(11))
_CACHE_SIZE = 4
_CACHE: "collections.OrderedDict[tuple, PrefilteredEnvironment]" = collections.OrderedDict()


@dataclasses.dataclass(frozen=True)
class PrefilteredEnvironment:
    """Everything :func:`split_sum` needs from one environment.

    Attributes:
        irradiance: ``[He, We, 3]`` lat-long irradiance ``E(n)`` (not divided by pi).
        specular: One ``[Hk, Wk, 3]`` lat-long map per level (level 0 = raw map).
        level_roughness: Increasing roughness of each level, first 0, last 1.
        lut: ``[S, S, 2]`` DFG table (rows roughness, columns NdotV).
    """

    irradiance: torch.Tensor
    specular: tuple
    level_roughness: tuple
    lut: torch.Tensor

    def to(self, device) -> "PrefilteredEnvironment":
        """The same environment with every tensor on ``device`` (no copy where already there)."""
        return dataclasses.replace(self, irradiance=self.irradiance.to(device),
                                   specular=tuple(m.to(device) for m in self.specular),
                                   lut=self.lut.to(device))


def _check_envmap(envmap) -> None:
    if not isinstance(envmap, torch.Tensor):
        raise TypeError(f"envmap must be a torch.Tensor, got {type(envmap).__name__}")
    if envmap.ndim != 3 or envmap.shape[2] != 3 or min(envmap.shape[:2]) < 1:
        raise ValueError(f"envmap must be [H, W, 3] (lat-long), got {tuple(envmap.shape)}")


def level_factor(height: int, width: int, target_rows: float) -> int:
    """Largest integer factor dividing ``height`` and ``width`` keeping >= target rows.

    Args:
        height: Rows of the source map.
        width: Columns of the source map.
        target_rows: Minimum number of rows wanted after downsampling.

    Returns:
        The factor ``f`` (1 when no reduction keeps enough rows).
    """
    g = math.gcd(height, width)
    best = 1
    for f in range(1, g + 1):
        if g % f == 0 and height / f >= target_rows:
            best = f
    return best


def irradiance_map(envmap: torch.Tensor, height: int = 64) -> torch.Tensor:
    """Diffuse irradiance ``E(n)`` on a downsampled lat-long grid.

    Args:
        envmap: ``[H, W, 3]`` linear radiance.
        height: Approximate rows of the result (at least this many when possible).

    Returns:
        ``[H/f, W/f, 3]`` irradiance (constant ``L`` gives ``pi L`` exactly).
    """
    _check_envmap(envmap)
    small = downsample_latlong(envmap, level_factor(*envmap.shape[:2], height))
    return math.pi * zonal_filter(small, lambda c: c.clamp_min(0.0), normalize=True)


def ggx_prefilter(envmap: torch.Tensor, roughness: float) -> torch.Tensor:
    """GGX-prefiltered map (N=V=R) on the grid of ``envmap``.

    Args:
        envmap: ``[H, W, 3]`` linear radiance (already at the level's resolution).
        roughness: Perceptual roughness ``r > 0`` (``alpha = r^2``).

    Returns:
        ``[H, W, 3]`` normalised weighted average of the radiance.
    """
    _check_envmap(envmap)
    if not roughness > 0:
        raise ValueError(f"roughness must be > 0 for prefiltering, got {roughness}")
    a2 = float(roughness) ** 4

    def kernel(c: torch.Tensor) -> torch.Tensor:
        # D(h) up to a constant with (R.h)^2 = (1 + c) / 2, times max(c, 0).
        denom = 1.0 - (1.0 - a2) * (1.0 + c) * 0.5
        return c.clamp_min(0.0) / (denom * denom)

    return zonal_filter(envmap, kernel, normalize=True)


def prefilter_environment(envmap: torch.Tensor, *,
                          level_roughness=DEFAULT_LEVEL_ROUGHNESS,
                          max_level_height: int = 256, min_level_height: int = 16,
                          irradiance_height: int = 64, lut_size: int = 128,
                          lut_samples: int = 1024) -> PrefilteredEnvironment:
    """Prefilter an environment for :func:`split_sum` (see module docstring).

    Args:
        envmap: ``[H, W, 3]`` linear HDR lat-long map (Z-up convention).
        level_roughness: Increasing roughness levels starting at 0, ending at 1.
        max_level_height: Upper bound on the rows of a prefiltered level (> 0).
        min_level_height: Lower bound on the rows of a prefiltered level.
        irradiance_height: Rows of the irradiance map (approximately).
        lut_size: DFG table resolution.
        lut_samples: DFG samples per texel.

    Returns:
        A :class:`PrefilteredEnvironment` on the device of ``envmap`` (float32).
    """
    _check_envmap(envmap)
    levels = tuple(float(r) for r in level_roughness)
    if (len(levels) < 2 or levels[0] != 0.0 or levels[-1] != 1.0
            or any(b <= a for a, b in zip(levels, levels[1:]))):
        raise ValueError(f"level_roughness must increase from 0 to 1, got {levels}")
    env = envmap.detach().to(torch.float32)
    h, w = env.shape[:2]
    maps = [env]
    for r in levels[1:]:
        target = min(max(math.pi / r ** 2, min_level_height), max_level_height)
        small = downsample_latlong(env, level_factor(h, w, target))
        maps.append(ggx_prefilter(small, r))
    lut = dfg_lut(lut_size, lut_samples).to(env.device)
    return PrefilteredEnvironment(irradiance_map(env, irradiance_height), tuple(maps),
                                  levels, lut)


def _cached_prefilter(envmap: torch.Tensor) -> PrefilteredEnvironment:
    """Prefilter with a small LRU keyed by the map's content hash."""
    data = envmap.detach().to(torch.float32).cpu().contiguous().numpy()
    key = (hashlib.blake2b(data.tobytes(), digest_size=16).hexdigest(),
           tuple(envmap.shape), str(envmap.device))
    hit = _CACHE.get(key)
    if hit is not None:
        _CACHE.move_to_end(key)
        return hit
    pre = prefilter_environment(envmap)
    _CACHE[key] = pre
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return pre


def clear_prefilter_cache() -> None:
    """Forget every cached :class:`PrefilteredEnvironment`."""
    _CACHE.clear()


def _sample_specular(pre: PrefilteredEnvironment, refl: torch.Tensor,
                     roughness: torch.Tensor) -> torch.Tensor:
    """Prefiltered radiance, linear in roughness between levels. Shapes [N,3],[N]->[N,3]."""
    levels = torch.tensor(pre.level_roughness, device=refl.device, dtype=refl.dtype)
    idx = (torch.searchsorted(levels, roughness.contiguous(), right=True) - 1)
    idx = idx.clamp(0, len(pre.level_roughness) - 2)
    t = ((roughness - levels[idx]) / (levels[idx + 1] - levels[idx])).clamp(0, 1)
    out = torch.zeros_like(refl)
    for k, level in enumerate(pre.specular):
        wk = torch.where(idx == k, 1 - t, torch.zeros_like(t)) + torch.where(
            idx + 1 == k, t, torch.zeros_like(t))
        sel = wk > 0
        if bool(sel.any()):
            vals = sample_latlong(level.to(refl.device), refl[sel])
            out[sel] += wk[sel, None] * vals
    return out


def split_sum(albedo: torch.Tensor, roughness: torch.Tensor, metallic: torch.Tensor,
              normal: torch.Tensor, view_dir: torch.Tensor, envmap) -> torch.Tensor:
    """Shade pixels with split-sum image-based lighting.

    Args:
        albedo: ``[..., 3]`` LINEAR base colour (decode sRGB before calling).
        roughness: ``[..., 1]`` perceptual roughness (clamped to [0, 1]).
        metallic: ``[..., 1]`` metalness (clamped to [0, 1]).
        normal: ``[..., 3]`` unit normals (renormalised defensively).
        view_dir: ``[..., 3]`` unit vectors from the surface towards the camera.
        envmap: ``[H, W, 3]`` linear HDR lat-long tensor (prefiltered once and
            cached by content), or a :class:`PrefilteredEnvironment`.

    Returns:
        ``[..., 3]`` linear radiance (not clamped, not tone-mapped), dtype of albedo.

    Raises:
        ValueError: If the shapes do not match the above.
    """
    tensors = dict(albedo=albedo, roughness=roughness, metallic=metallic,
                   normal=normal, view_dir=view_dir)
    for name, t in tensors.items():
        if not isinstance(t, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    lead = albedo.shape[:-1]
    for name, t in tensors.items():
        last = 1 if name in ("roughness", "metallic") else 3
        if t.ndim < 1 or t.shape[-1] != last or t.shape[:-1] != lead:
            raise ValueError(f"{name} must have shape {(*lead, last)} (albedo is "
                             f"{tuple(albedo.shape)}), got {tuple(t.shape)}")
    pre = envmap if isinstance(envmap, PrefilteredEnvironment) else None
    if pre is None:
        _check_envmap(envmap)
        pre = _cached_prefilter(envmap)
    f32 = dict(dtype=torch.float32)
    alb = albedo.reshape(-1, 3).to(**f32)
    rough = roughness.reshape(-1).to(**f32).clamp(0, 1)
    metal = metallic.reshape(-1, 1).to(**f32).clamp(0, 1)
    n = torch.nn.functional.normalize(normal.reshape(-1, 3).to(**f32), dim=-1)
    wo = torch.nn.functional.normalize(view_dir.reshape(-1, 3).to(**f32), dim=-1)
    n_dot_wo = (n * wo).sum(-1, keepdim=True)
    refl = 2 * n_dot_wo * n - wo
    n_dot_v = n_dot_wo[:, 0].clamp(1e-4, 1.0)
    f0 = 0.04 * (1 - metal) + alb * metal
    irr = sample_latlong(pre.irradiance.to(alb.device), n)
    diffuse = alb * (1 - metal) * irr / math.pi
    a, b = lookup_dfg(pre.lut, n_dot_v, rough)
    specular = _sample_specular(pre, refl, rough) * (f0 * a[:, None] + b[:, None])
    return (diffuse + specular).reshape(*lead, 3).to(albedo.dtype)
