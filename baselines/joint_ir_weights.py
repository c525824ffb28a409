"""Frozen-geometry rendering of per-surfel features as one sparse matrix per view.

With the geometry of a 2DGS asset frozen (the joint inverse-rendering baseline optimises
materials and lighting only), every composited feature map is LINEAR in the per-surfel
features: ``map[p] = sum_i w_{p,i} f_i`` with the alpha-blending weights
``w_{p,i} = alpha_i(p) T_i(p)``. This module extracts those weights once per view, so that
an optimisation step renders B views by sparse-dense products instead of re-rasterizing.

The weights come from the project's own compositor, not a re-derivation: for each tile
batch of ``gspi.gaussians.torch_backend.rasterize_view`` the surfel rows are given one-hot
"features" over the batch's list slots, so ``TileComposite`` (the rasterizer's fused
compositing function) returns exactly ``w`` per (pixel, slot). Rendering features with
:meth:`ViewWeights.render` therefore equals ``render_gaussians(...).features`` up to
float rounding (tested in ``tests/test_baselines_inhouse.py``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from gspi.gaussians.composite import TileComposite, pixel_basis
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.projection import project_surfels
from gspi.gaussians.rasterize import render_gaussians
# _chunk_rows is the rasterizer's own (tile -> padded surfel list) gather; reused rather
# than copied so the lists, their order and padding are the rasterizer's exactly.
from gspi.gaussians.torch_backend import _chunk_rows, surfel_table
from gspi.gaussians.tiles import bin_splats, pixel_bounds, plan_chunks

__all__ = ["ViewWeights", "compositing_weights"]


@dataclass
class ViewWeights:
    """One view's frozen compositing, restricted to pixels some surfel covers.

    Attributes:
        height, width: Image size in pixels.
        pixels: [P] flat pixel indices ``row * width + col``, increasing.
        matrix: [P, N] sparse CSR matrix of weights ``w_{p,i}`` (rows sum to ``alpha``).
        matrix_t: [N, P] its transpose, also CSR (the backward of :meth:`render`).
        alpha: [P] accumulated opacity.
        normals: [P, 3] unit world normals rendered by the rasterizer (2DGS normals).
    """

    height: int
    width: int
    pixels: Tensor
    matrix: Tensor
    matrix_t: Tensor
    alpha: Tensor
    normals: Tensor

    def render(self, features: Tensor) -> Tensor:
        """[P, D] composited (alpha-premultiplied, zero background) features of [N, D]."""
        return _SparseProduct.apply(self.matrix, self.matrix_t, features)

    def to_image(self, values: Tensor, background: float = 0.0) -> Tensor:
        """[P, D] per-pixel values -> [H, W, D] image (``background`` elsewhere)."""
        image = values.new_full((self.height * self.width, values.shape[-1]), background)
        image = image.index_copy(0, self.pixels, values)
        return image.reshape(self.height, self.width, -1)


class _SparseProduct(torch.autograd.Function):
    """``A @ x`` for a constant CSR ``A`` with the transpose precomputed for the backward.

    Hand-written because autograd of ``torch.sparse.mm`` transposes the CSR matrix on
    every call (measured 15x slower than two CSR products on a 128 px view).
    """

    @staticmethod
    def forward(ctx, matrix: Tensor, matrix_t: Tensor, x: Tensor) -> Tensor:
        ctx.matrix_t = matrix_t
        return matrix @ x

    @staticmethod
    def backward(ctx, grad: Tensor):
        return None, None, ctx.matrix_t @ grad.contiguous()


def _to_csr(matrix: Tensor) -> Tensor:
    """COO -> CSR, without torch's one-time "CSR support is in beta" warning."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return matrix.to_sparse_csr()


def _triplets(table: Tensor, bins, width: int, height: int, tile_size: int,
              max_elems: int) -> tuple[Tensor, Tensor, Tensor]:
    """(flat pixel, surfel, weight) of every composited pair with weight > 0."""
    p = tile_size * tile_size
    basis = pixel_basis(tile_size, table.dtype, table.device)
    local = torch.arange(p, device=table.device)
    pad_row = len(table) - 1
    pix_all, ids_all, w_all = [], [], []
    for tiles, k in plan_chunks(bins.counts, p, max_elems):
        rows, origin = _chunk_rows(bins, tiles, k, pad_row=pad_row)
        n = len(tiles)
        # one-hot channels cost n * seg^2: keep that within the budget too
        seg = max(1, min(k, max_elems // (n * p), int(math.sqrt(max_elems / n))))
        t = torch.ones(n, p, dtype=table.dtype, device=table.device)
        px = origin[:, 0, None] + local % tile_size  # [n, P]
        py = origin[:, 1, None] + local // tile_size
        for start in range(0, k, seg):
            r = rows[:, start:start + seg]
            s = r.shape[1]
            onehot = torch.eye(s, dtype=table.dtype, device=table.device).expand(n, s, s)
            g = torch.cat([table[r], onehot], dim=-1)
            w, _, _, _, _, t = TileComposite.apply(g, origin.to(table.dtype), t, basis, True)
            tile_i, pix_i, slot = torch.nonzero(w > 0, as_tuple=True)  # w: [n, P, S]
            x, y = px[tile_i, pix_i], py[tile_i, pix_i]
            inside = (x < width) & (y < height)
            pix_all.append((y * width + x)[inside])
            ids_all.append(r[tile_i, slot][inside])
            w_all.append(w[tile_i, pix_i, slot][inside])
    if not pix_all:
        empty = torch.zeros(0, dtype=torch.long, device=table.device)
        return empty, empty, torch.zeros(0, dtype=table.dtype, device=table.device)
    return torch.cat(pix_all), torch.cat(ids_all), torch.cat(w_all)


@torch.no_grad()
def compositing_weights(gaussians: Gaussians2D, viewmat: Tensor, K: Tensor, width: int,
                        height: int, *, tile_size: int = 8, max_elems: int = 1 << 20,
                        near_plane: float = 0.01, far_plane: float = 1e10) -> ViewWeights:
    """Alpha-blending weights of ``gaussians`` in one camera (torch rasterizer semantics).

    Args:
        gaussians: The frozen surfels (N).
        viewmat: [4, 4] world-to-camera (OpenCV).
        K: [3, 3] pixel intrinsics.
        width, height: Image size in pixels.
        tile_size, max_elems, near_plane, far_plane: As ``rasterize_2dgs``.

    Returns:
        :class:`ViewWeights` over the pixels with a positive weight.
    """
    viewmats, Ks = viewmat[None].float(), K[None].float()
    proj = project_surfels(gaussians.means, gaussians.quats, gaussians.scales, viewmats, Ks,
                           width, height, near_plane, far_plane)
    rt, means2d, depths = proj.ray_transforms[0], proj.means2d[0], proj.depths[0]
    opacities = gaussians.opacities
    in_range = (depths > near_plane) & (depths < far_plane)
    lo, hi, valid = pixel_bounds(rt, means2d, opacities, width, height)
    bins = bin_splats(lo, hi, valid & in_range, depths, width, height, tile_size)
    table = surfel_table(rt, means2d, depths, opacities, rt.new_zeros(len(rt), 0))
    pix, ids, w = _triplets(table, bins, width, height, tile_size, max_elems)
    pixels, row = torch.unique(pix, return_inverse=True)
    n = gaussians.num_gaussians
    index = torch.stack([row, ids])
    matrix = torch.sparse_coo_tensor(index, w, (len(pixels), n), check_invariants=False).coalesce()
    matrix_t = torch.sparse_coo_tensor(index.flip(0), w, (n, len(pixels)),
                                       check_invariants=False).coalesce()
    out = render_gaussians(gaussians, viewmats, Ks, width, height, backend="torch",
                           tile_size=tile_size, max_elems=max_elems)
    normals = out.normals_unit[0].reshape(-1, 3)[pixels]
    alpha = torch.sparse.sum(matrix, dim=1).to_dense()
    return ViewWeights(height, width, pixels, _to_csr(matrix), _to_csr(matrix_t), alpha, normals)
