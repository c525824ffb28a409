"""Split-sum DFG lookup table (computed here, not downloaded).

Layout (nvdiffrec's ``bsdf_256_256.bin`` convention, see method notes 4.1):
``lut[i, j] = (A, B)`` with row ``i`` = roughness and column ``j`` = NdotV,
both sampled at texel centres ``(i + 0.5) / S``. For a specular colour
``F0`` the directional albedo of the GGX microfacet BRDF is ``F0 * A + B``.

Integral (Karis 2013, height-correlated Smith as in nvdiffrec / GS-IR):
``alpha = roughness**2``, ``a2 = alpha**2``, ``V = (sqrt(1 - NoV^2), 0, NoV)``,
``H ~ GGX(alpha)`` by importance sampling with Hammersley points,
``L = reflect(-V, H)``; for ``NoL > 0``::

    Vis = 0.5 / (NoL sqrt(NoV^2 (1 - a2) + a2) + NoV sqrt(NoL^2 (1 - a2) + a2))
    G   = 4 Vis NoL VoH / NoH            # BRDF * cos / pdf, without Fresnel
    Fc  = (1 - VoH)^5                    # Schlick
    A   = mean(G (1 - Fc)),  B = mean(G Fc)

(samples with ``NoL <= 0`` contribute zero but still count in the mean).
"""

from __future__ import annotations

import functools
import math

import torch

__all__ = ["hammersley", "dfg_lut", "lookup_dfg"]


def hammersley(n: int, dtype=torch.float64) -> torch.Tensor:
    """Hammersley point set ``(i / n, radical_inverse_base2(i))``.

    Args:
        n: Number of points (< 2**32).
        dtype: Floating dtype of the result.

    Returns:
        Tensor ``[n, 2]`` in ``[0, 1)^2``.
    """
    i = torch.arange(n, dtype=torch.int64)
    bits = torch.zeros(n, dtype=torch.int64)
    for b in range(32):
        bits |= ((i >> b) & 1) << (31 - b)
    u2 = bits.to(torch.float64) / 2.0 ** 32
    return torch.stack([i.to(torch.float64) / n, u2], dim=-1).to(dtype)


def _dfg_rows(roughness: torch.Tensor, n_dot_v: torch.Tensor,
              xi: torch.Tensor) -> torch.Tensor:
    """DFG integral for a grid of roughness x NdotV.

    Args:
        roughness: ``[R]`` perceptual roughness.
        n_dot_v: ``[V]`` cosines in ``(0, 1]``.
        xi: ``[N, 2]`` low-discrepancy points.

    Returns:
        ``[R, V, 2]`` (A, B).
    """
    alpha = (roughness ** 2)[:, None, None]  # [R,1,1]
    a2 = alpha * alpha
    u1, u2 = xi[:, 0], xi[:, 1]  # [N]
    ph = 2 * math.pi * u1
    cos_h = torch.sqrt((1 - u2) / (1 + (a2 - 1) * u2))  # [R,1,N]
    sin_h = torch.sqrt((1 - cos_h * cos_h).clamp_min(0))
    hx, hz = sin_h * torch.cos(ph), cos_h  # hy is irrelevant: V has no y part
    nov = n_dot_v[None, :, None]  # [1,V,1]
    vx = torch.sqrt((1 - nov * nov).clamp_min(0))
    voh = vx * hx + nov * hz  # [R,V,N]
    nol = 2 * voh * hz - nov
    valid = (nol > 0) & (voh > 0)
    nol_c = nol.clamp_min(0)
    vis = 0.5 / (nol_c * torch.sqrt(nov * nov * (1 - a2) + a2)
                 + nov * torch.sqrt(nol_c * nol_c * (1 - a2) + a2))
    g = torch.where(valid, 4 * vis * nol_c * voh.clamp_min(0) / hz, torch.zeros_like(vis))
    fc = (1 - voh.clamp(0, 1)) ** 5
    return torch.stack([(g * (1 - fc)).mean(-1), (g * fc).mean(-1)], dim=-1)


@functools.lru_cache(maxsize=4)
def _dfg_lut_cached(size: int, samples: int) -> torch.Tensor:
    centres = (torch.arange(size, dtype=torch.float32) + 0.5) / size
    xi = hammersley(samples, torch.float32)
    rows_per_chunk = max(1, (1 << 22) // (size * samples))
    out = [_dfg_rows(centres[s:s + rows_per_chunk], centres, xi)
           for s in range(0, size, rows_per_chunk)]
    lut = torch.cat(out, dim=0).clamp(0.0, 1.0)
    lut.requires_grad_(False)
    return lut


def dfg_lut(size: int = 128, samples: int = 1024) -> torch.Tensor:
    """The DFG table, cached in-process per ``(size, samples)``.

    Args:
        size: Table resolution ``S`` (both axes).
        samples: Hammersley samples per texel.

    Returns:
        CPU float32 tensor ``[S, S, 2]``; rows = roughness, columns = NdotV,
        channel 0 = A (scale on F0), channel 1 = B (bias). Treat as read-only.
    """
    if size < 2 or samples < 1:
        raise ValueError(f"need size >= 2 and samples >= 1, got {size}, {samples}")
    return _dfg_lut_cached(int(size), int(samples))


def lookup_dfg(lut: torch.Tensor, n_dot_v: torch.Tensor,
               roughness: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Bilinear lookup with clamping to the edge texel centres.

    Args:
        lut: ``[S, S, 2]`` table from :func:`dfg_lut`.
        n_dot_v: ``[...]`` cosines (any shape broadcastable with ``roughness``).
        roughness: ``[...]`` perceptual roughness.

    Returns:
        ``(A, B)``, each of the broadcast shape of the inputs.
    """
    if lut.ndim != 3 or lut.shape[2] != 2 or lut.shape[0] != lut.shape[1]:
        raise ValueError(f"lut must be [S, S, 2], got {tuple(lut.shape)}")
    n_dot_v, roughness = torch.broadcast_tensors(n_dot_v, roughness)
    s = lut.shape[0]
    lut = lut.to(device=n_dot_v.device, dtype=n_dot_v.dtype)
    x = (n_dot_v * s - 0.5).clamp(0, s - 1)
    y = (roughness * s - 0.5).clamp(0, s - 1)
    x0f, y0f = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0f)[..., None], (y - y0f)[..., None]
    x0, y0 = x0f.long(), y0f.long()
    x1, y1 = (x0 + 1).clamp(max=s - 1), (y0 + 1).clamp(max=s - 1)
    top = lut[y0, x0] + (lut[y0, x1] - lut[y0, x0]) * fx
    bot = lut[y1, x0] + (lut[y1, x1] - lut[y1, x0]) * fx
    ab = top + (bot - top) * fy
    return ab[..., 0], ab[..., 1]
