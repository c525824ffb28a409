"""Screen-space tiling for the pure-torch 2DGS rasterizer.

Hand-written counterpart of gsplat's ``isect_tiles`` / ``isect_offset_encode``
(CUDA-only in gsplat). Differences from gsplat, on purpose:

* The box of a surfel covers every pixel where its alpha can reach 1/255: the
  exact box of the projected disc ``u^2 + v^2 <= 2 ln(255 * opacity)`` united
  with the low-pass filter's disc ``|p - means2d|^2 <= ln(255 * opacity)``.
  gsplat boxes ``3.33`` one-sigma extents only, so a sub-pixel surfel can be cut
  at a tile border there. Here nothing that passes the alpha threshold is ever
  dropped, so the tile renderer equals a dense all-pairs renderer.
* A projection that is not a bounded ellipse (the disc crosses the camera plane)
  gets the whole image as its box.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from gspi.gaussians.projection import conic_bounds

ALPHA_THRESHOLD = 1.0 / 255.0
# relative slack on the support radius so float rounding never drops a pixel at the edge
_SUPPORT_SLACK = 1e-3
# padding up to this many entries is accepted regardless of min_fill (short lists)
_PAD_SLACK = 8


@dataclass
class TileBins:
    """Surfel lists per tile, sorted front to back (by centre depth).

    Attributes:
        tile_size: tile side in pixels.
        tiles_x: number of tile columns.
        tiles_y: number of tile rows.
        splat_ids: [P] int64 surfel index of each (tile, surfel) pair, grouped by tile
            in row-major tile order, front to back inside a tile.
        offsets: [tiles_x * tiles_y + 1] int64 start of each tile's run in ``splat_ids``.
    """

    tile_size: int
    tiles_x: int
    tiles_y: int
    splat_ids: Tensor
    offsets: Tensor

    @property
    def counts(self) -> Tensor:
        """[tiles] number of surfels per tile."""
        return self.offsets[1:] - self.offsets[:-1]


@torch.no_grad()
def pixel_bounds(
    ray_transforms: Tensor,  # [N, 3, 3]
    means2d: Tensor,  # [N, 2]
    opacities: Tensor,  # [N]
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """Inclusive pixel-index box of every pixel a surfel can reach with alpha >= 1/255.

    Args:
        ray_transforms: [N, 3, 3] gsplat ray transforms (rows of ``K [s_u t_u, s_v t_v, mu_c]``).
        means2d: [N, 2] centre of the low-pass filter in pixels.
        opacities: [N] activated opacities.
        width: image width in pixels.
        height: image height in pixels.

    Returns:
        lo [N, 2] and hi [N, 2] int64 pixel indices (x, y), clamped to the image, and a
        bool mask [N] that is False where the box is empty or the opacity is below 1/255.
    """
    rho_max = 2.0 * torch.log(torch.clamp_min(opacities, 1e-30) / ALPHA_THRESHOLD)
    reach = rho_max > 0
    rho_max = torch.clamp_min(rho_max, 0.0) * (1.0 + _SUPPORT_SLACK) + _SUPPORT_SLACK
    center, half, bounded = conic_bounds(ray_transforms, torch.sqrt(rho_max))
    size = torch.tensor([width, height], dtype=center.dtype, device=center.device)
    big = torch.tensor(1e9, dtype=center.dtype, device=center.device)
    lo3 = torch.where(bounded[:, None], center - half, -big)
    hi3 = torch.where(bounded[:, None], center + half, big)
    r_filter = torch.sqrt(rho_max / 2.0)[:, None]
    lo = torch.minimum(lo3, means2d - r_filter)
    hi = torch.maximum(hi3, means2d + r_filter)
    finite = torch.isfinite(lo).all(-1) & torch.isfinite(hi).all(-1)
    # pixel j (centre j + 0.5) is inside [lo, hi] iff ceil(lo - 0.5) <= j <= floor(hi - 0.5)
    lo_px = torch.ceil(torch.clamp(lo, torch.full_like(size, -2.0), size + 2.0) - 0.5).long()
    hi_px = torch.floor(torch.clamp(hi, torch.full_like(size, -2.0), size + 2.0) - 0.5).long()
    limit = size.long() - 1
    lo_px = torch.maximum(lo_px, torch.zeros_like(lo_px))
    hi_px = torch.minimum(hi_px, limit)
    valid = reach & finite & (lo_px <= hi_px).all(-1)
    return lo_px, hi_px, valid


@torch.no_grad()
def bin_splats(
    lo_px: Tensor,  # [N, 2]
    hi_px: Tensor,  # [N, 2]
    valid: Tensor,  # [N]
    depths: Tensor,  # [N]
    width: int,
    height: int,
    tile_size: int,
) -> TileBins:
    """Lists, for every tile, the surfels whose pixel box overlaps it, front to back.

    Args:
        lo_px: [N, 2] first pixel (x, y) of each box, from :func:`pixel_bounds`.
        hi_px: [N, 2] last pixel (x, y), inclusive.
        valid: [N] bool, surfels to bin.
        depths: [N] centre depth used for the front-to-back order.
        width: image width in pixels.
        height: image height in pixels.
        tile_size: tile side in pixels.

    Returns:
        :class:`TileBins`.
    """
    device = lo_px.device
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    ids = torch.nonzero(valid).squeeze(1)
    t_lo = torch.div(lo_px[ids], tile_size, rounding_mode="floor")
    t_hi = torch.div(hi_px[ids], tile_size, rounding_mode="floor")
    span = t_hi - t_lo + 1  # [M, 2]
    per_splat = span[:, 0] * span[:, 1]
    owner = torch.repeat_interleave(torch.arange(len(ids), device=device), per_splat)
    start = torch.cumsum(per_splat, 0) - per_splat
    local = torch.arange(len(owner), device=device) - start[owner]
    tx = t_lo[owner, 0] + local % span[owner, 0]
    ty = t_lo[owner, 1] + torch.div(local, span[owner, 0], rounding_mode="floor")
    tile = ty * tiles_x + tx
    # rank of each surfel in the global front-to-back order, ties broken by index
    order = torch.argsort(depths[ids], stable=True)
    rank = torch.empty_like(order)
    rank[order] = torch.arange(len(order), device=device)
    key = tile * max(len(ids), 1) + rank[owner]
    perm = torch.argsort(key)
    counts = torch.bincount(tile, minlength=tiles_x * tiles_y)
    offsets = torch.zeros(tiles_x * tiles_y + 1, dtype=torch.long, device=device)
    offsets[1:] = torch.cumsum(counts, 0)
    return TileBins(tile_size, tiles_x, tiles_y, ids[owner[perm]], offsets)


def plan_chunks(
    counts: Tensor, pixels_per_tile: int, max_elems: int, min_fill: float = 0.7
) -> list[tuple[Tensor, int]]:
    """Groups non-empty tiles into batches that share one padded list length.

    Tiles are taken by decreasing list length; a batch keeps adding tiles while
    each new tile fills at least ``min_fill`` of the batch's length (or lacks at most
    8 entries) and the batch
    stays within ``max_elems`` (tiles x length x pixels). A single tile longer than
    the budget forms its own batch; the rasterizer then walks its list in segments
    carrying the transmittance, so no surfel is ever dropped.

    Args:
        counts: [tiles] surfels per tile.
        pixels_per_tile: tile_size ** 2.
        max_elems: element budget of one [tiles, length, pixels] batch.
        min_fill: lowest accepted ratio of a tile's length to the batch's length.

    Returns:
        List of (tile indices [n] int64, padded length K).
    """
    order = torch.argsort(counts, descending=True, stable=True)
    sorted_counts = counts[order].tolist()
    chunks: list[tuple[Tensor, int]] = []
    i = 0
    while i < len(sorted_counts) and sorted_counts[i] > 0:
        k = sorted_counts[i]
        j = i + 1
        while (
            j < len(sorted_counts)
            and sorted_counts[j] > 0
            and (sorted_counts[j] >= min_fill * k or k - sorted_counts[j] <= _PAD_SLACK)
            and (j - i + 1) * k * pixels_per_tile <= max_elems
        ):
            j += 1
        chunks.append((order[i:j], k))
        i = j
    return chunks
