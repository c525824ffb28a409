"""Compiled (numba) per-tile compositing of a whole view, with a hand-written backward.

The same math as :mod:`gspi.gaussians.composite` (the reference; see its module
docstring), looped the way gsplat's ``RasterizeToPixels2DGSFwd.cu`` /
``RasterizeToPixels2DGSBwd.cu`` loop instead of batched: one task per tile
(``numba.prange``, largest lists first), the tile's surfels front to back over
its pixels, each pixel stopping at gsplat's early termination. Per (surfel,
pixel centre (x, y)):

  ``(c0, c1, c2) = c + a x + b y`` (the row's homogeneous-plane cross products),
  ``r3 = min((c0^2 + c1^2) / c2^2, 1e30)``, ``r2 = 2 |(x, y) - means2d|^2``,
  ``rho = min(r3, r2)``, ``alpha = min(0.999, op exp(-rho / 2))``, 0 below 1/255
  or where ``|c2| <= sqrt(tiny)``; a pixel stops before the first surfel that
  would bring T to ``<= 1e-4``; ``w = alpha T``; median depth = z of the last
  surfel composited while ``T > 0.5``; z = ``det / c2`` where ``r3 <= r2`` in the
  intersection mode (hbb1), the centre depth otherwise.

Outputs per pixel: ``sum w chan``, ``sum w``, ``sum w z``, median depth (the
``[H, W, F + 3]`` image of ``torch_backend.rasterize_view``). The forward keeps
per pixel the final T, the end of its composited run and the median's list
slot; the backward walks each run back to front recovering ``T_i = T_{i+1} /
(1 - alpha_i)`` and the sum of the later ``w_k s_k`` (gsplat's scheme), so no
per-pair state is stored. A pair's gradient lands in its own row of a
[pairs, 14 + F] buffer (a tile is one task, so no two threads write a row),
then the rows are summed per surfel (a counting sort by surfel, then parallel
over surfels: no atomics, deterministic).

Arithmetic is float64 inside for both float32 and float64 tables; results
and gradients come back in the table's dtype.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from gspi.gaussians.composite import (
    _R3_CAP,
    ALPHA_MAX,
    ALPHA_THRESHOLD,
    COL_A,
    COL_B,
    COL_C,
    COL_CHAN,
    COL_DET,
    COL_LOGOP,
    COL_MEAN2D,
    COL_ZC,
    T_MEDIAN,
    T_STOP,
)
from gspi.gaussians.numba_jit import njit_cached, threads
from gspi.gaussians.tiles import TileBins

# exp(pre) < 1/255 for sure below this: skips the exp for most pairs; the exact test
# (exp, then compare, as composite.py does) decides every pair above it
_LOG_REJECT = math.log(ALPHA_THRESHOLD) - 1e-6


@njit_cached(inline="always")
def _row(table, i):
    """The 14 geometry / opacity / depth values of surfel row i as float64 scalars (kept
    in registers over a tile's pixels), plus the largest rho that can still pass 1/255."""
    geo = (float(table[i, 0]), float(table[i, 1]), float(table[i, 2]), float(table[i, 3]), float(table[i, 4]),
           float(table[i, 5]), float(table[i, 6]), float(table[i, 7]), float(table[i, 8]), float(table[i, 9]),
           float(table[i, 10]), float(table[i, 11]), float(table[i, 12]), float(table[i, 13]))
    return geo, 2.0 * (geo[COL_LOGOP] - _LOG_REJECT)


@njit_cached(inline="always")
def _evaluate(s, rho_max, x, y, intersection, eps_c2):
    """(alpha, z, c0, c1, 1 / c2, r3, r3 wins) of surfel ``s`` (:func:`_row`) at pixel centre (x, y)."""
    c0 = s[COL_C] + s[COL_A] * x + s[COL_B] * y
    c1 = s[COL_C + 1] + s[COL_A + 1] * x + s[COL_B + 1] * y
    c2 = s[COL_C + 2] + s[COL_A + 2] * x + s[COL_B + 2] * y
    dx = x - s[COL_MEAN2D]
    dy = y - s[COL_MEAN2D + 1]
    r2 = 2.0 * (dx * dx + dy * dy)
    q = c0 * c0 + c1 * c1
    # most pairs: both rho candidates beyond the 1/255 support, decided without a division
    # (r3 > rho_max <=> q > rho_max c2^2; rho_max carries the margin of _LOG_REJECT)
    if r2 > rho_max and q > rho_max * (c2 * c2):
        return 0.0, 0.0, c0, c1, 1.0, 0.0, False
    if abs(c2) <= eps_c2:  # ray parallel to the splat plane: skipped, as in gsplat
        return 0.0, 0.0, c0, c1, 1.0, 0.0, False
    inv = 1.0 / c2
    r3 = min(q * inv * inv, _R3_CAP)
    use_r3 = r3 <= r2
    pre = s[COL_LOGOP] - 0.5 * (r3 if use_r3 else r2)
    alpha = 0.0
    if pre >= _LOG_REJECT:
        e = math.exp(pre)
        if e >= ALPHA_THRESHOLD:
            alpha = min(e, ALPHA_MAX)
    z = s[COL_DET] * inv if (intersection and use_r3) else s[COL_ZC]
    return alpha, z, c0, c1, inv, r3, use_r3


@njit_cached(inline="always")
def _tile_extent(tile, grid):
    """First pixel (x0, y0) and in-image size (nx, ny) of a tile; grid = (tiles_x, tile_size, W, H)."""
    tiles_x, tile_size, width, height = grid
    x0 = (tile % tiles_x) * tile_size
    y0 = (tile // tiles_x) * tile_size
    return x0, y0, min(tile_size, width - x0), min(tile_size, height - y0)


@njit_cached(inline="always")
def _clip(lo, hi, i, x0, y0, nx, ny):
    """Tile-local pixel range [bx0, bx1) x [by0, by1) of surfel i's support box (tiles.pixel_bounds:
    every pixel where its alpha can reach 1/255; the others would be rejected anyway)."""
    bx0, by0 = max(lo[i, 0] - x0, 0), max(lo[i, 1] - y0, 0)
    bx1, by1 = min(hi[i, 0] - x0 + 1, nx), min(hi[i, 1] - y0 + 1, ny)
    return bx0, bx1, by0, by1


@njit_cached()
def _forward_tile(tile, table, ids, offsets, lo, hi, grid, intersection, eps_c2, out, t_final, last, median):
    start, stop = offsets[tile], offsets[tile + 1]
    if start == stop:
        return  # the caller initialised the empty image
    n_chan = table.shape[1] - COL_CHAN
    x0, y0, nx, ny = _tile_extent(tile, grid)
    trans = np.ones((ny, nx))
    alive = np.ones((ny, nx), np.bool_)
    acc = np.zeros((ny, nx, n_chan + 3))
    end = np.full((ny, nx), start, np.int64)
    med = np.full((ny, nx), -1, np.int64)
    n_alive = nx * ny
    for k in range(start, stop):
        if n_alive == 0:
            break
        i = ids[k]
        s, rho_max = _row(table, i)
        bx0, bx1, by0, by1 = _clip(lo, hi, i, x0, y0, nx, ny)
        for ly in range(by0, by1):
            for lx in range(bx0, bx1):
                if not alive[ly, lx]:
                    continue
                alpha, z, _, _, _, _, _ = _evaluate(s, rho_max, x0 + lx + 0.5, y0 + ly + 0.5, intersection, eps_c2)
                if alpha == 0.0:
                    continue
                t = trans[ly, lx]
                t_next = t * (1.0 - alpha)
                if t_next <= T_STOP:  # gsplat's early termination: this surfel is not composited
                    alive[ly, lx] = False
                    n_alive -= 1
                    continue
                w = alpha * t
                for f in range(n_chan):
                    acc[ly, lx, f] += w * table[i, COL_CHAN + f]
                acc[ly, lx, n_chan] += w
                acc[ly, lx, n_chan + 1] += w * z
                if t > T_MEDIAN:
                    acc[ly, lx, n_chan + 2] = z
                    med[ly, lx] = k
                trans[ly, lx] = t_next
                end[ly, lx] = k + 1
    for ly in range(ny):
        for lx in range(nx):
            y, x = y0 + ly, x0 + lx
            for f in range(n_chan + 3):
                out[y, x, f] = acc[ly, lx, f]
            t_final[y, x] = trans[ly, lx]
            last[y, x] = end[ly, lx]
            median[y, x] = med[ly, lx]


@njit_cached(parallel=True)
def _forward(order, table, ids, offsets, lo, hi, grid, intersection, eps_c2, out, t_final, last, median):
    for j in numba.prange(len(order)):
        _forward_tile(order[j], table, ids, offsets, lo, hi, grid, intersection, eps_c2, out, t_final, last, median)


@njit_cached(inline="always")
def _pair_gradient(s, x, y, z, c0, c1, inv, r3, use_r3, intersection, d_pre, d_z):
    """One pair's (dL/d log op, dL/d means2d x, y, dL/d det, dL/d centre z, dL/d (c0, c1, c2))
    from dL/d(log op - rho / 2) and dL/dz."""
    d_rho = -0.5 * d_pre
    d_mx = d_my = dc0 = dc1 = dc2 = d_det = d_zc = 0.0
    if use_r3:  # rho = r3 = (c0^2 + c1^2) / c2^2
        k3 = d_rho * inv
        dc0 = 2.0 * inv * k3 * c0
        dc1 = 2.0 * inv * k3 * c1
        dc2 = -2.0 * k3 * r3
    else:  # rho = r2 = 2 |p - means2d|^2
        d_mx = -4.0 * (x - s[COL_MEAN2D]) * d_rho
        d_my = -4.0 * (y - s[COL_MEAN2D + 1]) * d_rho
    if intersection and use_r3:  # z = det / c2
        d_det = d_z * inv
        dc2 -= d_det * z
    else:
        d_zc = d_z
    return d_pre, d_mx, d_my, d_det, d_zc, dc0, dc1, dc2


@njit_cached()
def _backward_tile(tile, table, ids, offsets, lo, hi, grid, intersection, eps_c2,
                   g_out, t_final, last, median, grad_pairs):
    start = offsets[tile]
    if start == offsets[tile + 1]:
        return
    n_chan = table.shape[1] - COL_CHAN
    x0, y0, nx, ny = _tile_extent(tile, grid)
    trans = t_final[y0:y0 + ny, x0:x0 + nx].copy()  # T after each pixel's run, divided back below
    end = last[y0:y0 + ny, x0:x0 + nx]
    later = np.zeros((ny, nx))  # sum over the later composited surfels of w_k dL/dw_k
    k_max = max(start, end.max())
    d_chan = np.empty(n_chan)
    # the surfel's 14 geometry gradients summed over the tile's pixels. A small array, not 14
    # scalar accumulators: with scalars numba's code ran the backward 3.7x slower (34.2 vs
    # 9.3 ms, demo asset s006, 128 px, one thread; same bits), the 9 plane-coefficient sums
    # alone costing ~25 ms
    acc = np.zeros(COL_CHAN)
    for k in range(k_max - 1, start - 1, -1):
        i = ids[k]
        s, rho_max = _row(table, i)
        bx0, bx1, by0, by1 = _clip(lo, hi, i, x0, y0, nx, ny)
        d_chan[:] = 0.0
        acc[:] = 0.0
        for ly in range(by0, by1):
            for lx in range(bx0, bx1):
                if k >= end[ly, lx]:
                    continue
                x, y = x0 + lx + 0.5, y0 + ly + 0.5
                alpha, z, c0, c1, inv, r3, use_r3 = _evaluate(s, rho_max, x, y, intersection, eps_c2)
                if alpha == 0.0:
                    continue
                py, px = y0 + ly, x0 + lx
                one_m = 1.0 - alpha
                t_before = trans[ly, lx] / one_m
                w = alpha * t_before
                d_w = g_out[py, px, n_chan] + z * g_out[py, px, n_chan + 1]  # dL/dw of this pair
                for f in range(n_chan):
                    g_f = g_out[py, px, f]
                    d_w += table[i, COL_CHAN + f] * g_f
                    d_chan[f] += w * g_f
                d_alpha = t_before * d_w - later[ly, lx] / one_m
                later[ly, lx] += w * d_w
                trans[ly, lx] = t_before
                d_z = w * g_out[py, px, n_chan + 1]
                if k == median[py, px]:
                    d_z += g_out[py, px, n_chan + 2]
                # clamped alpha (0.999) has no gradient w.r.t. opacity or rho
                d_pre = d_alpha * alpha if alpha < ALPHA_MAX else 0.0
                d_lop, d_mx, d_my, d_det, d_zc, dc0, dc1, dc2 = _pair_gradient(
                    s, x, y, z, c0, c1, inv, r3, use_r3, intersection, d_pre, d_z)
                # c_j = c + a x + b y; columns COL_A .. COL_ZC in order
                acc[0] += dc0 * x
                acc[1] += dc1 * x
                acc[2] += dc2 * x
                acc[3] += dc0 * y
                acc[4] += dc1 * y
                acc[5] += dc2 * y
                acc[6] += dc0
                acc[7] += dc1
                acc[8] += dc2
                acc[9] += d_det
                acc[10] += d_mx
                acc[11] += d_my
                acc[12] += d_lop
                acc[13] += d_zc
        for j in range(COL_CHAN):
            grad_pairs[k, j] = acc[j]
        for f in range(n_chan):
            grad_pairs[k, COL_CHAN + f] = d_chan[f]


@njit_cached(parallel=True)
def _backward(order, table, ids, offsets, lo, hi, grid, intersection, eps_c2, g_out, t_final, last, median,
              grad_pairs):
    for j in numba.prange(len(order)):
        _backward_tile(order[j], table, ids, offsets, lo, hi, grid, intersection, eps_c2, g_out, t_final, last,
                       median, grad_pairs)


@njit_cached()
def _group_pairs(ids, n_rows):
    """Counting sort of the pair slots by surfel: slots of surfel i are perm[starts[i]:starts[i + 1]]."""
    starts = np.zeros(n_rows + 1, np.int64)
    for k in range(len(ids)):
        starts[ids[k] + 1] += 1
    for i in range(n_rows):
        starts[i + 1] += starts[i]
    fill = starts[:-1].copy()
    perm = np.empty(len(ids), np.int64)
    for k in range(len(ids)):
        perm[fill[ids[k]]] = k
        fill[ids[k]] += 1
    return starts, perm


@njit_cached(parallel=True)
def _sum_pairs(ids, grad_pairs, grad_table):
    """grad_table[i] = sum of the pair rows of surfel i; one surfel per task, so no write races."""
    starts, perm = _group_pairs(ids, grad_table.shape[0])
    for i in numba.prange(grad_table.shape[0]):
        for j in range(starts[i], starts[i + 1]):
            for c in range(grad_table.shape[1]):
                grad_table[i, c] += grad_pairs[perm[j], c]


def _tile_order(offsets: np.ndarray, workers: int = 1) -> np.ndarray:
    """Tiles by decreasing list length, dealt to ``workers`` like cards in a snake (0, 1, ..,
    w-1, w-1, .., 0, 0, ..) and laid out worker by worker. Numba's workqueue layer hands each
    thread one contiguous, equal share of a prange whatever ``parallel_chunksize`` says (so a
    plain longest-first order gave one thread all the long tiles: two threads ran 1.0-1.17x
    one); dealt this way every share holds long and short tiles alike. Each tile writes only
    its own pixels and pair rows, so the order never changes a result."""
    order = np.argsort(-(offsets[1:] - offsets[:-1]), kind="stable").astype(np.int64)
    if workers <= 1:
        return order
    rank = np.arange(len(order))
    row, col = rank // workers, rank % workers
    owner = np.where(row % 2 == 0, col, workers - 1 - col)
    return np.concatenate([order[owner == w] for w in range(workers)])


def _arrays(*tensors: Tensor) -> list[np.ndarray]:
    return [t.detach().contiguous().numpy() for t in tensors]


class NumbaComposite(torch.autograd.Function):
    """Composites every tile of one view; differentiable w.r.t. the surfel table.

    Inputs: table [N + 1, 14 + F] (``torch_backend.surfel_table``), ids / offsets
    (``TileBins.splat_ids`` / ``offsets``, int64), lo / hi [N, 2] int64 support
    boxes (``tiles.pixel_bounds``), grid (tiles_x, tile_size, width, height),
    intersection (bool). Output: [H, W, F + 3] channels, weight sum, sum of w z,
    median depth (0 where none).
    """

    @staticmethod
    def forward(ctx, table, ids, offsets, lo, hi, grid, intersection):
        tab, ids_np, off_np, lo_np, hi_np = _arrays(table, ids, offsets, lo, hi)
        width, height = grid[2], grid[3]
        out = np.zeros((height, width, tab.shape[1] - COL_CHAN + 3), tab.dtype)
        t_final = np.ones((height, width))
        last = np.zeros((height, width), np.int64)
        median = np.full((height, width), -1, np.int64)
        eps_c2 = float(torch.finfo(table.dtype).tiny) ** 0.5
        workers = threads()
        numba.set_num_threads(workers)
        with numba.parallel_chunksize(1):  # tiles differ widely in cost: hand them out one by one
            _forward(_tile_order(off_np, workers), tab, ids_np, off_np, lo_np, hi_np, grid, intersection, eps_c2,
                     out, t_final, last, median)
        ctx.options = (grid, intersection, eps_c2)
        ctx.save_for_backward(table, ids, offsets, lo, hi, *map(torch.from_numpy, (t_final, last, median)))
        return torch.from_numpy(out)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_out):
        grid, intersection, eps_c2 = ctx.options
        table = ctx.saved_tensors[0]
        tab, ids_np, off_np, lo_np, hi_np, t_final, last, median = _arrays(*ctx.saved_tensors)
        (g_np,) = _arrays(g_out.to(table.dtype))
        grad_pairs = np.zeros((len(ids_np), tab.shape[1]), tab.dtype)  # rows a tile's loop never reaches stay 0
        grad_table = np.zeros_like(tab)
        workers = threads()
        numba.set_num_threads(workers)
        with numba.parallel_chunksize(1):
            _backward(_tile_order(off_np, workers), tab, ids_np, off_np, lo_np, hi_np, grid, intersection, eps_c2,
                      g_np, t_final, last, median, grad_pairs)
        _sum_pairs(ids_np, grad_pairs, grad_table)
        return torch.from_numpy(grad_table), None, None, None, None, None, None


def _check(table: Tensor, bins: TileBins, lo: Tensor, hi: Tensor, width: int, height: int) -> None:
    if table.device.type != "cpu":
        raise ValueError(f"the numba compositor runs on CPU tensors, got a {table.device.type} table")
    if table.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"the numba compositor needs a float32 or float64 table, got {table.dtype}")
    if table.dim() != 2 or table.shape[1] < COL_CHAN:
        raise ValueError(f"surfel table must be [N + 1, {COL_CHAN} + F], got {tuple(table.shape)}")
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width} x {height}")
    if bins.tiles_x * bins.tile_size < width or bins.tiles_y * bins.tile_size < height:
        raise ValueError(f"tiles {bins.tiles_x} x {bins.tiles_y} of {bins.tile_size} px do not cover "
                         f"{width} x {height}")
    if len(bins.offsets) != bins.tiles_x * bins.tiles_y + 1 or int(bins.offsets[-1]) != len(bins.splat_ids):
        raise ValueError("tile offsets do not match the tile grid / the surfel id list")
    if lo.shape != hi.shape or lo.dim() != 2 or lo.shape[1] != 2:
        raise ValueError(f"support boxes lo / hi must be [N, 2], got {tuple(lo.shape)} / {tuple(hi.shape)}")
    rows = min(len(table), len(lo))
    if len(bins.splat_ids) and not (0 <= int(bins.splat_ids.min()) and int(bins.splat_ids.max()) < rows):
        raise ValueError("tile lists index rows outside the surfel table or the support boxes")


def composite_view(table: Tensor, bins: TileBins, lo: Tensor, hi: Tensor, width: int, height: int,
                   intersection_depth: bool) -> Tensor:
    """[H, W, F + 3] image (channels, alpha, sum of w z, median depth) of one binned view.

    Args:
        table: [N + 1, 14 + F] surfel rows (``torch_backend.surfel_table``), float32 or float64, CPU.
        bins: the view's front-to-back tile lists (``tiles.bin_splats``).
        lo: [N, 2] first pixel (x, y) of each surfel's support box (``tiles.pixel_bounds``).
        hi: [N, 2] last pixel (x, y), inclusive.
        width: image width in pixels.
        height: image height in pixels.
        intersection_depth: hbb1's depth rule (True) or the centre depth (False).
    """
    _check(table, bins, lo, hi, width, height)
    grid = (int(bins.tiles_x), int(bins.tile_size), int(width), int(height))
    as_long = [t.to(torch.int64) for t in (bins.splat_ids, bins.offsets, lo, hi)]
    return NumbaComposite.apply(table, *as_long, grid, bool(intersection_depth))
