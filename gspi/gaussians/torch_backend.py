"""Tile-based pure-torch 2DGS rasterizer (one view).

Hand-written because gsplat's ``rasterize_to_pixels_2dgs`` is CUDA-only and its
torch reference needs nerfacc's CUDA scans. Steps: pixel boxes and (tile,
surfel) lists sorted front to back by centre depth (``tiles.py``); tiles with
similar list lengths are batched and padded with an invisible surfel; each
batch is evaluated and composited as one [tiles, surfels, pixels] block by
:class:`~gspi.gaussians.composite.TileComposite` (semantics of gsplat's
``RasterizeToPixels2DGSFwd.cu``, see there); lists longer than the batch
budget are walked in segments carrying the transmittance, never truncated.
``composite="numba"`` hands the same table and lists to the compiled per-tile
loops of ``numba_composite.py`` instead (CPU; equal outputs and gradients).

The ray-splat intersection uses the homogeneous-plane method:
``h_u x h_v = x (M1 x M2) + y (M2 x M0) + M0 x M1`` is affine in the pixel
(x, y), so a surfel stores three 3-vectors, and the intersection depth is
``z = det(M) / (h_u x h_v)[2]`` (used where the surfel kernel wins the low-pass
min, hbb1's rule; the centre depth elsewhere).
"""

from __future__ import annotations

import torch
from torch import Tensor

from gspi.gaussians.composite import COL_CHAN, COL_LOGOP, COL_MEAN2D, COL_ZC, TileComposite, pixel_basis
from gspi.gaussians.tiles import TileBins, bin_splats, pixel_bounds, plan_chunks

_DUMMY_LOG_OPACITY = -1e4  # padding entries: alpha = 0, never composited


def surfel_table(
    ray_transforms: Tensor,  # [N, 3, 3]
    means2d: Tensor,  # [N, 2]
    depths: Tensor,  # [N]
    opacities: Tensor,  # [N]
    channels: Tensor,  # [N, F]
) -> Tensor:
    """Packs everything a pixel needs about a surfel into one row (+ a padding row).

    Returns:
        [N + 1, 14 + F]: M1 x M2, M2 x M0, M0 x M1, det M, means2d, log opacity,
        centre depth, channels; row N is an invisible padding surfel.
    """
    m0, m1, m2 = ray_transforms.unbind(-2)
    a = torch.linalg.cross(m1, m2, dim=-1)
    b = torch.linalg.cross(m2, m0, dim=-1)
    c = torch.linalg.cross(m0, m1, dim=-1)
    det = (m0 * a).sum(-1, keepdim=True)
    log_op = torch.log(torch.clamp_min(opacities, 1e-30))[:, None]
    return padded_table(torch.cat([a, b, c, det, means2d, log_op, depths[:, None], channels], dim=-1))


def padded_table(rows: Tensor) -> Tensor:
    """[N, 14 + F] surfel rows plus the invisible padding row the tile lists point at."""
    pad = torch.zeros_like(rows[:1])
    pad[:, COL_LOGOP] = _DUMMY_LOG_OPACITY
    return torch.cat([rows, pad], dim=0)


def _composite_chunk(
    table: Tensor, rows: Tensor, origin: Tensor, basis: Tensor, max_elems: int, intersection_depth: bool
) -> Tensor:
    """Composites tiles sharing a padded list ``rows`` [n, K] (surfel indices, N = padding).

    Walks the list in segments that fit ``max_elems``, carrying transmittance, so
    an overfull tile is split, never truncated.

    Returns:
        [n, P, F + 3]: channels, weight sum (alpha), sum of w z, median depth.
    """
    n, k = rows.shape
    p = basis.shape[1]
    seg = max(1, min(k, max_elems // (n * p)))
    t = torch.ones(n, p, dtype=table.dtype, device=table.device)
    chan = wsum = wz = z_med = None
    for start in range(0, k, seg):
        g = table[rows[:, start : start + seg]]  # [n, S, 14 + F]
        c, a, d, zm, has, t = TileComposite.apply(g, origin, t, basis, intersection_depth)
        if chan is None:
            chan, wsum, wz, z_med = c, a, d, zm
        else:
            chan, wsum, wz, z_med = chan + c, wsum + a, wz + d, torch.where(has, zm, z_med)
    return torch.cat([chan, torch.stack([wsum, wz, z_med], dim=-1)], dim=-1)


def _chunk_rows(bins: TileBins, tiles: Tensor, k: int, pad_row: int) -> tuple[Tensor, Tensor]:
    """Surfel rows [n, k] of ``tiles`` (front to back, padded with ``pad_row``) and the
    tiles' pixel origins [n, 2] (x, y)."""
    counts = bins.counts[tiles, None]
    slot = torch.arange(k, device=tiles.device)
    index = (bins.offsets[tiles, None] + slot).clamp_max(max(len(bins.splat_ids) - 1, 0))
    rows = torch.where(slot < counts, bins.splat_ids[index], pad_row)
    origin = torch.stack([tiles % bins.tiles_x, torch.div(tiles, bins.tiles_x, rounding_mode="floor")], -1)
    return rows, origin * bins.tile_size


def rasterize_view(
    ray_transforms: Tensor,  # [N, 3, 3]
    means2d: Tensor,  # [N, 2]
    depths: Tensor,  # [N]
    opacities: Tensor,  # [N]
    channels: Tensor,  # [N, F]
    in_range: Tensor,  # [N] bool
    width: int,
    height: int,
    *,
    tile_size: int = 8,
    intersection_depth: bool = True,
    max_elems: int = 1 << 20,
    composite: str = "torch",
) -> Tensor:
    """Rasterizes one view with square tiles of ``tile_size`` pixels.

    Args:
        ray_transforms: [N, 3, 3] gsplat ray transforms for this camera.
        means2d: [N, 2] low-pass filter centres (pixels).
        depths: [N] centre depths (sort key, and the depth in "center" mode).
        opacities: [N] activated opacities in [0, 1].
        channels: [N, F] values to composite (colours, features, normals, ...).
        in_range: [N] bool, surfels whose centre lies between the near and far planes.
        width: image width in pixels.
        height: image height in pixels.
        tile_size: tile side in pixels.
        intersection_depth: True for hbb1's depth rule (ray-splat intersection depth where
            the surfel kernel wins the low-pass min), False for the centre depth (gsplat).
        max_elems: budget of surfel-pixel pairs per batched op (memory / speed knob).
        composite: "torch" (batched :class:`TileComposite`, the reference, any device) or
            "numba" (compiled per-tile loops, ``numba_composite.py``, CPU; same outputs and
            gradients; ``max_elems`` unused).

    Returns:
        [H, W, F + 3]: composited channels (over zero), alpha, sum of w z, median depth.
    """
    table = surfel_table(ray_transforms, means2d, depths, opacities, channels)
    return rasterize_table(table, ray_transforms, opacities, in_range, width, height, tile_size=tile_size,
                           intersection_depth=intersection_depth, max_elems=max_elems, composite=composite)


def rasterize_table(
    table: Tensor,  # [N + 1, 14 + F]
    ray_transforms: Tensor,  # [N, 3, 3]
    opacities: Tensor,  # [N]
    in_range: Tensor,  # [N] bool
    width: int,
    height: int,
    *,
    tile_size: int = 8,
    intersection_depth: bool = True,
    max_elems: int = 1 << 20,
    composite: str = "torch",
) -> Tensor:
    """:func:`rasterize_view` of a view whose surfel table is built (:func:`surfel_table`, or
    ``numba_projection.project_view``'s geometry columns + channels through :func:`padded_table`):
    bins the surfels by their support boxes and composites. Returns [H, W, F + 3]."""
    with torch.no_grad():
        means2d, depths = table[:-1, COL_MEAN2D:COL_MEAN2D + 2], table[:-1, COL_ZC]
        lo, hi, valid = pixel_bounds(ray_transforms, means2d, opacities, width, height)
    if composite == "numba":  # the same lists binned by a counting sort, compiled compositing
        from gspi.gaussians.numba_composite import composite_view
        from gspi.gaussians.numba_tiles import bin_splats_numba

        bins = bin_splats_numba(lo, hi, valid & in_range, depths, width, height, tile_size)
        return composite_view(table, bins, lo, hi, width, height, intersection_depth)
    if composite != "torch":
        raise ValueError(f"composite must be 'torch' or 'numba', got {composite!r}")
    bins = bin_splats(lo, hi, valid & in_range, depths, width, height, tile_size)
    return composite_tiles(table, bins, width, height, intersection_depth, max_elems)


def composite_tiles(table: Tensor, bins: TileBins, width: int, height: int, intersection_depth: bool,
                    max_elems: int = 1 << 20) -> Tensor:
    """The reference compositing of a binned view: batches of padded tile lists through
    :class:`TileComposite`. Returns [H, W, F + 3] like :func:`rasterize_view`."""
    tile_size = bins.tile_size
    n_tiles, p = bins.tiles_x * bins.tiles_y, tile_size * tile_size
    canvas = torch.zeros(n_tiles, p, table.shape[1] - COL_CHAN + 3, dtype=table.dtype, device=table.device)
    basis = pixel_basis(tile_size, table.dtype, table.device)
    done, parts = [], []
    for tiles, k in plan_chunks(bins.counts, p, max_elems):
        rows, origin = _chunk_rows(bins, tiles, k, pad_row=len(table) - 1)
        parts.append(_composite_chunk(table, rows, origin.to(table.dtype), basis, max_elems, intersection_depth))
        done.append(tiles)
    if parts:
        canvas = canvas.index_copy(0, torch.cat(done), torch.cat(parts))
    else:
        # keep the (all-zero) image attached to the graph so backward() still works
        canvas = canvas + 0.0 * table[:-1].sum()
    image = canvas.reshape(bins.tiles_y, bins.tiles_x, tile_size, tile_size, -1)
    image = image.permute(0, 2, 1, 3, 4).reshape(bins.tiles_y * tile_size, bins.tiles_x * tile_size, -1)
    return image[:height, :width]
