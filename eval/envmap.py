"""Lat-long environment maps: the project's fixed convention and helpers.

Convention (TensoIR's, world Z-up like Blender / NeRF-synthetic):

* An environment is an ``H x W x 3`` tensor of *linear* HDR radiance.
* Pixel (row ``r``, column ``c``) has elevation
  ``phi = pi/2 - (r + 0.5) * pi / H`` and azimuth
  ``theta = pi - (c + 0.5) * 2 * pi / W``; its direction is
  ``d = (cos(theta) cos(phi), sin(theta) cos(phi), sin(phi))``.
  Row 0 is next to ``+z`` (zenith), the last row next to ``-z``; the centre
  column boundary (``c = W/2``) is azimuth 0, i.e. the ``+x`` direction, and
  the left edge of the map is azimuth ``+pi`` (``-x``); azimuth decreases
  to the right (column ``W/4`` boundary is ``+y``).
* Lookups are bilinear on texel centres, wrap around in azimuth and are
  clamped to the first / last row towards the poles.

Every function here is pure torch, works on any device, and does no work at
import time. ``eval`` never imports ``gspi``.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

__all__ = [
    "latlong_directions",
    "latlong_solid_angles",
    "direction_to_pixel",
    "sample_latlong",
    "bilinear_latlong",
    "downsample_latlong",
    "zonal_filter",
]


def _elevations(height: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Elevation ``phi`` of each row centre, shape ``[H]``."""
    r = torch.arange(height, device=device, dtype=torch.float64)
    return (math.pi / 2 - (r + 0.5) * math.pi / height).to(dtype)


def _azimuths(width: int, device=None, dtype=torch.float32) -> torch.Tensor:
    """Azimuth ``theta`` of each column centre, shape ``[W]``."""
    c = torch.arange(width, device=device, dtype=torch.float64)
    return (math.pi - (c + 0.5) * 2 * math.pi / width).to(dtype)


def latlong_directions(height: int, width: int, device=None,
                       dtype=torch.float32) -> torch.Tensor:
    """Unit direction of every texel centre.

    Args:
        height: Rows ``H``.
        width: Columns ``W``.
        device: Torch device of the result.
        dtype: Floating dtype of the result.

    Returns:
        Tensor ``[H, W, 3]`` of unit vectors (Z-up convention above).
    """
    phi = _elevations(height, device, torch.float64)[:, None]
    theta = _azimuths(width, device, torch.float64)[None, :]
    d = torch.stack(torch.broadcast_tensors(
        torch.cos(theta) * torch.cos(phi), torch.sin(theta) * torch.cos(phi),
        torch.sin(phi).expand(height, width)), dim=-1)
    return d.to(dtype)


def latlong_solid_angles(height: int, width: int, device=None,
                         dtype=torch.float32) -> torch.Tensor:
    """Exact solid angle of the texels of each row.

    A texel of row ``r`` spans elevations ``[pi/2 - (r+1) pi/H, pi/2 - r pi/H]``
    and ``2 pi / W`` of azimuth, so its solid angle is
    ``(2 pi / W) * (sin(phi_top) - sin(phi_bottom))``; they sum to ``4 pi``.

    Args:
        height: Rows ``H``.
        width: Columns ``W``.
        device: Torch device of the result.
        dtype: Floating dtype of the result.

    Returns:
        Tensor ``[H, 1]`` (broadcasts against ``[H, W]``).
    """
    r = torch.arange(height + 1, device=device, dtype=torch.float64)
    s = torch.sin(math.pi / 2 - r * math.pi / height)
    return ((s[:-1] - s[1:]) * (2 * math.pi / width))[:, None].to(dtype)


def direction_to_pixel(directions: torch.Tensor, height: int,
                       width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Continuous (row, column) coordinates of directions, texel centres at integers.

    Args:
        directions: ``[..., 3]`` directions (need not be unit length).
        height: Rows ``H`` of the map.
        width: Columns ``W`` of the map.

    Returns:
        ``(row, col)``, each ``[...]``; ``row`` is unclamped, ``col`` unwrapped.
    """
    x, y, z = directions.unbind(-1)
    phi = torch.atan2(z, torch.sqrt(x * x + y * y))
    theta = torch.atan2(y, x)
    row = (math.pi / 2 - phi) * (height / math.pi) - 0.5
    col = (math.pi - theta) * (width / (2 * math.pi)) - 0.5
    return row, col


def sample_latlong(envmap: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of a lat-long map (azimuth wraps, poles clamp).

    Args:
        envmap: ``[H, W, C]`` map.
        directions: ``[..., 3]`` directions, any leading shape.

    Returns:
        ``[..., C]`` values, dtype of ``envmap``.

    Raises:
        ValueError: On malformed shapes.
    """
    if envmap.ndim != 3:
        raise ValueError(f"envmap must be [H, W, C], got shape {tuple(envmap.shape)}")
    if directions.shape[-1:] != (3,):
        raise ValueError(f"directions must be [..., 3], got {tuple(directions.shape)}")
    h, w, _ = envmap.shape
    lead = directions.shape[:-1]
    row, col = direction_to_pixel(directions.reshape(-1, 3).to(torch.float32), h, w)
    return bilinear_latlong(envmap, row, col).reshape(*lead, envmap.shape[2])


def bilinear_latlong(envmap: torch.Tensor, row: torch.Tensor, col: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup at continuous pixel coordinates [N] (``direction_to_pixel``'s: texel centres
    at integers, rows clamped at the poles, columns wrapped) -> [N, C], dtype of ``envmap``."""
    h, w, ch = envmap.shape
    row = row.clamp(0.0, h - 1.0)
    r0f = torch.floor(row)
    fr = (row - r0f)[:, None].to(envmap.dtype)
    r0 = r0f.long()
    r1 = (r0 + 1).clamp(max=h - 1)
    c0f = torch.floor(col)
    fc = (col - c0f)[:, None].to(envmap.dtype)
    c0 = torch.remainder(c0f.long(), w)
    c1 = torch.remainder(c0 + 1, w)
    flat = envmap.reshape(h * w, ch)
    v00, v01 = flat[r0 * w + c0], flat[r0 * w + c1]
    v10, v11 = flat[r1 * w + c0], flat[r1 * w + c1]
    top = v00 + (v01 - v00) * fc
    bot = v10 + (v11 - v10) * fc
    return top + (bot - top) * fr


def downsample_latlong(envmap: torch.Tensor, factor: int) -> torch.Tensor:
    """Solid-angle-weighted (area) average over ``factor x factor`` blocks.

    Preserves the integral of radiance over the sphere exactly.

    Args:
        envmap: ``[H, W, C]`` map; ``H`` and ``W`` must be divisible by ``factor``.
        factor: Positive integer reduction factor.

    Returns:
        ``[H // factor, W // factor, C]`` map.
    """
    if envmap.ndim != 3:
        raise ValueError(f"envmap must be [H, W, C], got shape {tuple(envmap.shape)}")
    h, w, ch = envmap.shape
    if factor < 1 or h % factor or w % factor:
        raise ValueError(f"factor {factor} must be >= 1 and divide H={h} and W={w}")
    if factor == 1:
        return envmap
    sa = latlong_solid_angles(h, w, envmap.device, envmap.dtype)  # [H, 1]
    weighted = (envmap * sa[:, :, None]).reshape(h // factor, factor, w // factor,
                                                 factor, ch).sum(dim=(1, 3))
    norm = sa.reshape(h // factor, factor).sum(1) * factor  # [H/f]
    return weighted / norm[:, None, None]


def zonal_filter(envmap: torch.Tensor, kernel: Callable[[torch.Tensor], torch.Tensor],
                 normalize: bool = True, max_chunk: int = 1 << 23) -> torch.Tensor:
    """Brute-force spherical filtering with a zonal kernel, evaluated exactly.

    For every texel direction ``n`` computes
    ``out(n) = sum_w K(n.w) L(w) dOmega(w)`` over *all* texels ``w``
    (divided by ``sum_w K(n.w) dOmega(w)`` when ``normalize``). Because
    ``n.w`` only depends on the two rows and the column difference, each row
    pair is a circular correlation along azimuth, summed here with an FFT:
    the same numbers as the O((HW)^2) double sum, at O(H^2 W log W) cost.
    Work is chunked over output rows to bound memory (``max_chunk`` kernel
    entries at a time).

    Args:
        envmap: ``[H, W, C]`` map.
        kernel: Maps cosines ``[...]`` to non-negative weights ``[...]``.
        normalize: Divide by the kernel's discrete integral.
        max_chunk: Upper bound on kernel entries held at once.

    Returns:
        ``[H, W, C]`` filtered map on the same grid.
    """
    h, w, ch = envmap.shape
    dev = envmap.device
    phi = _elevations(h, dev, torch.float64)
    j = torch.arange(w, device=dev, dtype=torch.float64)
    dtheta = torch.minimum(j, w - j) * (2 * math.pi / w)  # exactly symmetric in j
    cos_dt = torch.cos(dtheta).to(torch.float32)  # [W]
    sa = latlong_solid_angles(h, w, dev, torch.float32)[:, 0]  # [H]
    cc = (torch.cos(phi)[:, None] * torch.cos(phi)[None, :]).to(torch.float32)
    ss = (torch.sin(phi)[:, None] * torch.sin(phi)[None, :]).to(torch.float32)
    env_hat = torch.fft.rfft(envmap.to(torch.float32), dim=1)  # [H, F, C] complex
    nf = env_hat.shape[1]
    env_hat = torch.view_as_real(env_hat).permute(1, 0, 2, 3).reshape(nf, h, 2 * ch)
    out = torch.empty(h, w, ch, device=dev, dtype=torch.float32)
    rows = max(1, min(h, max_chunk // (h * w)))
    for start in range(0, h, rows):
        sl = slice(start, min(h, start + rows))
        cosines = cc[sl, :, None] * cos_dt + ss[sl, :, None]  # [o, H, W]
        k = kernel(cosines.clamp(-1.0, 1.0)) * sa[None, :, None]
        # k is even in the column offset, so its spectrum is real.
        k_hat = torch.fft.rfft(k, dim=2).real.permute(2, 0, 1).contiguous()  # [F, o, H]
        acc = torch.bmm(k_hat, env_hat)  # [F, o, 2C]: sum_i k_hat[f, o, i] env_hat[f, i]
        acc = torch.view_as_complex(acc.reshape(nf, -1, ch, 2).contiguous())
        res = torch.fft.irfft(acc.permute(1, 0, 2), n=w, dim=1)  # [o, W, C]
        if normalize:
            res = res / k.sum(dim=(1, 2)).clamp_min(1e-30)[:, None, None]
        out[sl] = res
    return out.to(envmap.dtype)
