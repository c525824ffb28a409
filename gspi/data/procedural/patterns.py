"""3D procedural patterns evaluated at surface points (pure torch, deterministic).

Every function takes object-space points `q` [N, 3] (unit-sphere frame of
`gspi.data.procedural.sdf_shapes.ShapeSDF.local`) and an integer `seed`, and returns per-point values
on the device of `q`; there is no texture image, so material boundaries are exact at any
resolution and supersampling integrates them. Hashing is integer arithmetic on int64 (wrap-around is
deterministic), so the same seed gives the same pattern on every machine.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

_MASK31 = 0x7FFFFFFF


def hash_int(ix: Tensor, iy: Tensor, iz: Tensor, seed: int) -> Tensor:
    """Integer lattice coordinates (int64, any shape) -> well-mixed 31-bit int64 hashes."""
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791) ^ (seed * 2654435761)
    h = h & _MASK31
    for _ in range(3):  # avalanche (xorshift-multiply), kept in 31 bits
        h = ((h >> 15) ^ h) * 0x2C1B3C6D & _MASK31
    return h


def unit_from_hash(h: Tensor, salt: int = 0) -> Tensor:
    """A hash from `hash_int` -> uniform float in [0, 1), one value per `salt`."""
    h = ((h ^ (salt * 0x27D4EB2F & _MASK31)) * 0x297A2D39) & _MASK31
    h = ((h >> 13) ^ h) & _MASK31
    return h.to(torch.float32) / float(_MASK31 + 1)


def hash3(ix: Tensor, iy: Tensor, iz: Tensor, seed: int, salt: int = 0) -> Tensor:
    """Integer lattice coordinates (int64, any shape) -> uniform floats in [0, 1)."""
    return unit_from_hash(hash_int(ix, iy, iz, seed), salt)


def _split(q: Tensor) -> tuple[Tensor, Tensor]:
    cell = torch.floor(q)
    return cell.to(torch.int64), q - cell


def value_noise(q: Tensor, seed: int) -> Tensor:
    """Trilinear value noise with smoothstep weights; [N, 3] -> [N] in [0, 1)."""
    cell, f = _split(q)
    w = f * f * (3.0 - 2.0 * f)
    out = torch.zeros(q.shape[0], dtype=q.dtype, device=q.device)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                h = hash3(cell[:, 0] + dx, cell[:, 1] + dy, cell[:, 2] + dz, seed)
                wx = w[:, 0] if dx else 1 - w[:, 0]
                wy = w[:, 1] if dy else 1 - w[:, 1]
                wz = w[:, 2] if dz else 1 - w[:, 2]
                out = out + wx * wy * wz * h
    return out


def fbm(q: Tensor, seed: int, *, octaves: int = 4, lacunarity: float = 2.0,
        gain: float = 0.5) -> Tensor:
    """Fractal sum of value noise, normalised to [0, 1); [N, 3] -> [N]."""
    total, amp, norm, freq = torch.zeros(q.shape[0], dtype=q.dtype, device=q.device), 1.0, 0.0, 1.0
    for k in range(octaves):
        total = total + amp * value_noise(q * freq, seed + 1013 * k)
        norm += amp
        amp *= gain
        freq *= lacunarity
    return total / norm


def voronoi(q: Tensor, seed: int) -> tuple[Tensor, Tensor, Tensor]:
    """Cellular (Worley) pattern with one jittered feature point per unit cell.

    All 27 neighbouring cells are evaluated at once ([N, 27] tensors).

    Returns:
        f1 [N] distance to the nearest feature point, f2 [N] to the second nearest,
        cell_id [N] float in [0, 1): a hash of the nearest cell (constant per region).
    """
    cell, f = _split(q)
    r = torch.arange(-1, 2, device=q.device)
    offsets = torch.stack(torch.meshgrid(r, r, r, indexing="ij"), dim=-1).reshape(1, 27, 3)
    nb = cell[:, None, :] + offsets                                   # [N, 27, 3] int64
    h = hash_int(nb[..., 0], nb[..., 1], nb[..., 2], seed)           # [N, 27]
    jit = torch.stack([unit_from_hash(h, s) for s in (1, 2, 3)], dim=-1)
    d = (offsets.to(q.dtype) + jit - f[:, None, :]).norm(dim=-1)      # [N, 27]
    two = torch.topk(d, 2, dim=1, largest=False)
    nearest = h.gather(1, two.indices[:, :1])[:, 0]
    return two.values[:, 0], two.values[:, 1], unit_from_hash(nearest, 7)


def checker(q: Tensor, frequency: float) -> Tensor:
    """3D checkerboard; [N, 3] -> [N] bool."""
    c = torch.floor(q * frequency).to(torch.int64).sum(dim=-1)
    return (c % 2) == 1


def stripes(q: Tensor, axis: Tensor, frequency: float, duty: float = 0.5) -> Tensor:
    """Parallel slabs across `axis` [3]; [N, 3] -> [N] bool, `duty` = fraction set."""
    s = (q @ axis) * frequency
    return (s - torch.floor(s)) < duty


def glyph_stripes(q: Tensor, seed: int, *, lines: float = 5.0, glyphs_per_turn: float = 28.0,
                  band: tuple[float, float] = (-0.6, 0.6)) -> Tensor:
    """Text-like marks: rows of pseudo-random 3x5 "glyphs" running around the z axis.

    Rows are horizontal bands (in z, within `band`); along a row the azimuth is cut into glyph
    cells separated by thin gaps and occasional word spaces; each glyph lights a random subset
    of its 3x5 sub-cells. High-frequency, binary, like printed labels.

    Returns:
        [N] bool (ink).
    """
    z = q[:, 2]
    inside = (z > band[0]) & (z < band[1])
    row_f = (z - band[0]) * lines
    row = torch.floor(row_f)
    v = row_f - row                                   # position within the row, [0, 1)
    on_row = (v > 0.25) & (v < 0.75)
    az = (torch.atan2(q[:, 1], q[:, 0]) / (2 * math.pi) + 0.5) * glyphs_per_turn
    col = torch.floor(az)
    u = az - col                                      # position within the glyph cell
    row_i, col_i = row.to(torch.int64), col.to(torch.int64)
    word_space = hash3(col_i, row_i, torch.zeros_like(col_i), seed, 11) < 0.18
    in_glyph = (u > 0.12) & (u < 0.88)
    gx = torch.clamp(((u - 0.12) / 0.76 * 3).floor(), 0, 2).to(torch.int64)
    gy = torch.clamp(((v - 0.25) / 0.5 * 5).floor(), 0, 4).to(torch.int64)
    bit = hash3(col_i * 3 + gx, row_i * 5 + gy, torch.ones_like(col_i), seed, 13) < 0.55
    return inside & on_row & in_glyph & ~word_space & bit


def brushed(q: Tensor, seed: int, axis: int = 2) -> Tensor:
    """Anisotropic streaks (value noise squashed along `axis`), [N] in [0, 1)."""
    scale = torch.full((3,), 90.0, device=q.device)
    scale[axis] = 2.0
    return value_noise(q * scale, seed)


def part_regions(q: Tensor, parts: dict) -> Tensor:
    """[N] long: which part of a multi-part object (``gspi.data.procedural.material_parts``) each point is in:
    ``bands`` = how many of the sorted ``cuts`` the warped coordinate along ``axis`` passes,
    ``cells`` = the nearest of ``centres`` by warped distance."""
    warp = parts["warp"] * (value_noise(q * 2.5, int(parts["noise_seed"])) - 0.5)
    if parts["layout"] == "bands":
        axis = torch.tensor(parts["axis"], dtype=q.dtype, device=q.device)
        cuts = torch.tensor(parts["cuts"], dtype=q.dtype, device=q.device)
        return ((q @ axis + warp)[:, None] > cuts[None, :]).sum(dim=1)
    centres = torch.tensor(parts["centres"], dtype=q.dtype, device=q.device)
    return (torch.cdist(q, centres) + warp[:, None]).argmin(dim=1)
