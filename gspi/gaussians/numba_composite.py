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
then the rows are summed per surfel (parallel over columns, deterministic).

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
    _R3_CAP, ALPHA_MAX, ALPHA_THRESHOLD, COL_A, COL_B, COL_C, COL_CHAN, COL_DET, COL_LOGOP, COL_MEAN2D,
    COL_ZC, T_MEDIAN, T_STOP,
)
from gspi.gaussians.numba_jit import njit_cached, threads
from gspi.gaussians.tiles import TileBins

# exp(pre) < 1/255 for sure below this: skips the exp for most pairs; the exact test
# (exp, then compare, as composite.py does) decides every pair above it
_LOG_REJECT = math.log(ALPHA_THRESHOLD) - 1e-6


@njit_cached()
def _evaluate(s, x, y, intersection, eps_c2):
    """(alpha, z, c0, c1, 1 / c2, r3, r3 wins) of surfel row ``s`` at pixel centre (x, y)."""
    c0 = s[COL_C] + s[COL_A] * x + s[COL_B] * y
    c1 = s[COL_C + 1] + s[COL_A + 1] * x + s[COL_B + 1] * y
    c2 = s[COL_C + 2] + s[COL_A + 2] * x + s[COL_B + 2] * y
    dx = x - s[COL_MEAN2D]
    dy = y - s[COL_MEAN2D + 1]
    r2 = 2.0 * (dx * dx + dy * dy)
    if abs(c2) <= eps_c2:  # ray parallel to the splat plane: skipped, as in gsplat
        return 0.0, 0.0, c0, c1, 1.0, 0.0, False
    inv = 1.0 / c2
    r3 = min((c0 * c0 + c1 * c1) * inv * inv, _R3_CAP)
    use_r3 = r3 <= r2
    pre = s[COL_LOGOP] - 0.5 * (r3 if use_r3 else r2)
    alpha = 0.0
    if pre >= _LOG_REJECT:
        e = math.exp(pre)
        if e >= ALPHA_THRESHOLD:
            alpha = min(e, ALPHA_MAX)
    z = s[COL_DET] * inv if (intersection and use_r3) else s[COL_ZC] * 1.0
    return alpha, z, c0, c1, inv, r3, use_r3


@njit_cached()
def _tile_pixels(tile, tiles_x, tile_size, width, height):
    """Pixel (x, y) indices of a tile's in-image pixels, row-major."""
    x0 = (tile % tiles_x) * tile_size
    y0 = (tile // tiles_x) * tile_size
    nx = min(tile_size, width - x0)
    ny = min(tile_size, height - y0)
    xs = np.empty(nx * ny, np.int64)
    ys = np.empty(nx * ny, np.int64)
    for p in range(nx * ny):
        xs[p] = x0 + p % nx
        ys[p] = y0 + p // nx
    return xs, ys


@njit_cached()
def _forward_tile(tile, table, ids, offsets, tiles_x, tile_size, width, height, intersection, eps_c2,
                  out, t_final, last, median):
    start, stop = offsets[tile], offsets[tile + 1]
    if start == stop:
        return  # the caller initialised the empty image
    n_chan = table.shape[1] - COL_CHAN
    xs, ys = _tile_pixels(tile, tiles_x, tile_size, width, height)
    n_pix = len(xs)
    trans = np.ones(n_pix)
    alive = np.ones(n_pix, np.bool_)
    acc = np.zeros((n_pix, n_chan + 3))
    end = np.full(n_pix, start, np.int64)
    med = np.full(n_pix, -1, np.int64)
    n_alive = n_pix
    for k in range(start, stop):
        if n_alive == 0:
            break
        s = table[ids[k]]
        for p in range(n_pix):
            if not alive[p]:
                continue
            alpha, z, _, _, _, _, _ = _evaluate(s, xs[p] + 0.5, ys[p] + 0.5, intersection, eps_c2)
            if alpha == 0.0:
                continue
            t_next = trans[p] * (1.0 - alpha)
            if t_next <= T_STOP:  # gsplat's early termination: this surfel is not composited
                alive[p] = False
                n_alive -= 1
                continue
            w = alpha * trans[p]
            for f in range(n_chan):
                acc[p, f] += w * s[COL_CHAN + f]
            acc[p, n_chan] += w
            acc[p, n_chan + 1] += w * z
            if trans[p] > T_MEDIAN:
                acc[p, n_chan + 2] = z
                med[p] = k
            trans[p] = t_next
            end[p] = k + 1
    for p in range(n_pix):
        x, y = xs[p], ys[p]
        for f in range(n_chan + 3):
            out[y, x, f] = acc[p, f]
        t_final[y, x] = trans[p]
        last[y, x] = end[p]
        median[y, x] = med[p]


@njit_cached(parallel=True)
def _forward(order, table, ids, offsets, tiles_x, tile_size, width, height, intersection, eps_c2,
             out, t_final, last, median):
    for i in numba.prange(len(order)):
        _forward_tile(order[i], table, ids, offsets, tiles_x, tile_size, width, height, intersection, eps_c2,
                      out, t_final, last, median)


@njit_cached()
def _backward_pair(s, x, y, z, c0, c1, inv, r3, use_r3, intersection, d_pre, d_z, gacc):
    """Adds one pair's geometry gradient to ``gacc`` given dL/d(log op - rho / 2) and dL/dz."""
    d_rho = -0.5 * d_pre
    gacc[COL_LOGOP] += d_pre
    dc0 = dc1 = dc2 = 0.0
    if use_r3:  # rho = r3 = (c0^2 + c1^2) / c2^2
        k3 = d_rho * inv
        dc0 = 2.0 * inv * k3 * c0
        dc1 = 2.0 * inv * k3 * c1
        dc2 = -2.0 * k3 * r3
    else:  # rho = r2 = 2 |p - means2d|^2
        gacc[COL_MEAN2D] -= 4.0 * (x - s[COL_MEAN2D]) * d_rho
        gacc[COL_MEAN2D + 1] -= 4.0 * (y - s[COL_MEAN2D + 1]) * d_rho
    if intersection and use_r3:  # z = det / c2
        d_det = d_z * inv
        gacc[COL_DET] += d_det
        dc2 -= d_det * z
    else:
        gacc[COL_ZC] += d_z
    for j, dc in enumerate((dc0, dc1, dc2)):  # c_j = c + a x + b y
        gacc[COL_A + j] += dc * x
        gacc[COL_B + j] += dc * y
        gacc[COL_C + j] += dc


@njit_cached()
def _backward_tile(tile, table, ids, offsets, tiles_x, tile_size, width, height, intersection, eps_c2,
                   g_out, t_final, last, median, grad_pairs):
    start = offsets[tile]
    if start == offsets[tile + 1]:
        return
    n_chan = table.shape[1] - COL_CHAN
    xs, ys = _tile_pixels(tile, tiles_x, tile_size, width, height)
    n_pix = len(xs)
    trans = np.empty(n_pix)
    later = np.zeros(n_pix)  # sum over the later composited surfels of w_k dL/dw_k
    end = np.empty(n_pix, np.int64)
    k_max = start
    for p in range(n_pix):
        trans[p] = t_final[ys[p], xs[p]]
        end[p] = last[ys[p], xs[p]]
        k_max = max(k_max, end[p])
    gacc = np.empty(table.shape[1])
    for k in range(k_max - 1, start - 1, -1):
        s = table[ids[k]]
        gacc[:] = 0.0
        for p in range(n_pix):
            if k >= end[p]:
                continue
            x, y = xs[p] + 0.5, ys[p] + 0.5
            alpha, z, c0, c1, inv, r3, use_r3 = _evaluate(s, x, y, intersection, eps_c2)
            if alpha == 0.0:
                continue
            g = g_out[ys[p], xs[p]]
            one_m = 1.0 - alpha
            t_before = trans[p] / one_m
            w = alpha * t_before
            d_w = g[n_chan] + z * g[n_chan + 1]  # dL/dw of this pair
            for f in range(n_chan):
                d_w += s[COL_CHAN + f] * g[f]
                gacc[COL_CHAN + f] += w * g[f]
            d_alpha = t_before * d_w - later[p] / one_m
            later[p] += w * d_w
            trans[p] = t_before
            d_z = w * g[n_chan + 1]
            if k == median[ys[p], xs[p]]:
                d_z += g[n_chan + 2]
            # clamped alpha (0.999) has no gradient w.r.t. opacity or rho
            d_pre = d_alpha * alpha if alpha < ALPHA_MAX else 0.0
            _backward_pair(s, x, y, z, c0, c1, inv, r3, use_r3, intersection, d_pre, d_z, gacc)
        for c in range(len(gacc)):
            grad_pairs[k, c] = gacc[c]


@njit_cached(parallel=True)
def _backward(order, table, ids, offsets, tiles_x, tile_size, width, height, intersection, eps_c2,
              g_out, t_final, last, median, grad_pairs):
    for i in numba.prange(len(order)):
        _backward_tile(order[i], table, ids, offsets, tiles_x, tile_size, width, height, intersection, eps_c2,
                       g_out, t_final, last, median, grad_pairs)


@njit_cached(parallel=True)
def _sum_pairs(ids, grad_pairs, grad_table):
    """grad_table[ids[k]] += grad_pairs[k]; one column per task, so no write races."""
    for c in numba.prange(grad_pairs.shape[1]):
        for k in range(len(ids)):
            grad_table[ids[k], c] += grad_pairs[k, c]


def _tile_order(offsets: np.ndarray) -> np.ndarray:
    """Tiles by decreasing list length (longest first balances the threads)."""
    return np.argsort(-(offsets[1:] - offsets[:-1]), kind="stable").astype(np.int64)


class NumbaComposite(torch.autograd.Function):
    """Composites every tile of one view; differentiable w.r.t. the surfel table.

    Inputs: table [N + 1, 14 + F] (``torch_backend.surfel_table``), ids / offsets
    (``TileBins.splat_ids`` / ``offsets``), tiles_x, tile_size, width, height,
    intersection (bool). Output: [H, W, F + 3] channels, weight sum, sum of w z,
    median depth (0 where none).
    """

    @staticmethod
    def forward(ctx, table, ids, offsets, tiles_x, tile_size, width, height, intersection):
        tab = table.detach().contiguous().numpy()
        ids_np, off_np = ids.contiguous().numpy(), offsets.contiguous().numpy()
        n_chan = tab.shape[1] - COL_CHAN
        out = np.zeros((height, width, n_chan + 3), tab.dtype)
        t_final = np.ones((height, width))
        last = np.zeros((height, width), np.int64)
        median = np.full((height, width), -1, np.int64)
        order = _tile_order(off_np)
        eps_c2 = float(torch.finfo(table.dtype).tiny) ** 0.5
        numba.set_num_threads(threads())
        with numba.parallel_chunksize(1):
            _forward(order, tab, ids_np, off_np, tiles_x, tile_size, width, height, bool(intersection), eps_c2,
                     out, t_final, last, median)
        ctx.geometry = (tiles_x, tile_size, width, height, bool(intersection), eps_c2)
        ctx.save_for_backward(table, ids, offsets, torch.from_numpy(t_final), torch.from_numpy(last),
                              torch.from_numpy(median))
        return torch.from_numpy(out)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_out):
        table, ids, offsets, t_final, last, median = ctx.saved_tensors
        tiles_x, tile_size, width, height, intersection, eps_c2 = ctx.geometry
        tab = table.detach().contiguous().numpy()
        ids_np, off_np = ids.contiguous().numpy(), offsets.contiguous().numpy()
        g_np = g_out.detach().to(table.dtype).contiguous().numpy()
        grad_pairs = np.zeros((len(ids_np), tab.shape[1]), tab.dtype)
        grad_table = np.zeros_like(tab)
        numba.set_num_threads(threads())
        with numba.parallel_chunksize(1):
            _backward(_tile_order(off_np), tab, ids_np, off_np, tiles_x, tile_size, width, height, intersection,
                      eps_c2, g_np, t_final.numpy(), last.numpy(), median.numpy(), grad_pairs)
        _sum_pairs(ids_np, grad_pairs, grad_table)
        return torch.from_numpy(grad_table), None, None, None, None, None, None, None


def _check(table: Tensor, bins: TileBins, width: int, height: int) -> None:
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
    if len(bins.splat_ids) and not (0 <= int(bins.splat_ids.min()) and int(bins.splat_ids.max()) < len(table)):
        raise ValueError("tile lists index rows outside the surfel table")


def composite_view(table: Tensor, bins: TileBins, width: int, height: int, intersection_depth: bool) -> Tensor:
    """[H, W, F + 3] image (channels, alpha, sum of w z, median depth) of one binned view.

    Args:
        table: [N + 1, 14 + F] surfel rows (``torch_backend.surfel_table``), float32 or float64, CPU.
        bins: the view's front-to-back tile lists (``tiles.bin_splats``).
        width: image width in pixels.
        height: image height in pixels.
        intersection_depth: hbb1's depth rule (True) or the centre depth (False).
    """
    _check(table, bins, width, height)
    ids = bins.splat_ids.to(torch.int64)
    offsets = bins.offsets.to(torch.int64)
    return NumbaComposite.apply(table, ids, offsets, bins.tiles_x, bins.tile_size, width, height,
                                bool(intersection_depth))
