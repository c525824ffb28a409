"""Fused per-tile evaluation and alpha compositing with a hand-written backward.

Autograd through the ~35 elementwise ops of a [tiles, surfels, pixels] batch
is memory-bound and keeps every intermediate; this ``autograd.Function`` runs
the forward in place, saves only alpha and transmittance, and writes the
backward out (the same derivation as gsplat's ``RasterizeToPixels2DGSBwd.cu``,
vectorised over a tile's list instead of looping back to front).

Per (surfel i, pixel p) of a tile with local pixel centres (lx, ly):
  geometry ``[c0, c1, c2, r2] = coef_i @ [1, lx, ly, lx^2 + ly^2]`` where
  (c0, c1, c2) is the homogeneous-plane cross product ``h_u x h_v`` (affine in
  the pixel) and ``r2 = 2 |p - means2d|^2`` (quadratic in the pixel);
  ``rho = min((c0^2 + c1^2) / c2^2, r2)``; ``alpha = min(0.999, op exp(-rho/2))``,
  0 below 1/255; ``T`` = exclusive product of (1 - alpha) times the carried
  transmittance ``t0``; surfels with inclusive ``T <= 1e-4`` are masked (exactly
  gsplat's early termination, as T never increases); ``w = alpha T``.
Outputs per pixel: ``sum w chan``, ``sum w``, ``sum w z``, median depth
(z of the last surfel composited while T > 0.5) and the transmittance after
the list. Depth z: hbb1's rule (``diff-surfel-rasterization`` forward.cu), the
ray-splat intersection depth ``det(M) / c2`` where the surfel kernel wins the
low-pass min (``u^2 + v^2 <= r2``) and the centre depth where the screen-space
filter wins; or the centre depth everywhere (gsplat).
"""

from __future__ import annotations

import torch
from torch import Tensor

ALPHA_THRESHOLD = 1.0 / 255.0
ALPHA_MAX = 0.999  # gsplat's clamp (hbb1: 0.99)
T_STOP = 1e-4
T_MEDIAN = 0.5
_R3_CAP = 1e30
# columns of a gathered surfel row (see torch_backend.surfel_table)
COL_A, COL_B, COL_C, COL_DET, COL_MEAN2D, COL_LOGOP, COL_ZC, COL_CHAN = 0, 3, 6, 9, 10, 12, 13, 14


def pixel_basis(tile_size: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """[4, P] basis ``(1, lx, ly, lx^2 + ly^2)`` of tile-local pixel centres (row-major)."""
    local = torch.arange(tile_size, dtype=dtype, device=device) + 0.5
    ly, lx = torch.meshgrid(local, local, indexing="ij")
    lx, ly = lx.reshape(-1), ly.reshape(-1)
    return torch.stack([torch.ones_like(lx), lx, ly, lx * lx + ly * ly])


def _geometry(coef: Tensor, basis: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """c0, c1, r2, u^2 + v^2 [n, S, P], mask where c2 ~ 0, and 1 / c2 (1 there)."""
    geo = torch.matmul(coef, basis)  # [n, S, 4, P]
    c0, c1, c2, r2 = geo.unbind(2)
    # gsplat skips ray_cross.z == 0; a tiny threshold also keeps 1 / c2^2 finite
    degenerate = c2.abs() <= torch.finfo(coef.dtype).tiny ** 0.5
    inv = torch.where(degenerate, 1.0, c2).reciprocal_()
    # u^2 + v^2, capped so that 0 * r3 stays 0 in the backward (the cap never wins the min)
    r3 = (c0 * c0).addcmul_(c1, c1).mul_(inv).mul_(inv).clamp_max_(_R3_CAP)
    return c0, c1, r2, r3, degenerate, inv


def _depth(use_r3: Tensor, det: Tensor, inv: Tensor, z_center: Tensor) -> Tensor:
    """hbb1's per-pixel surfel depth: ray-splat intersection z = det / c2 where the
    surfel kernel wins the low-pass min (rho3d <= rho2d), else the centre depth."""
    return torch.where(use_r3, det[..., None] * inv, z_center[..., None])


def coefficients(g: Tensor, origin: Tensor) -> Tensor:
    """[n, S, 4, 4] rows giving (c0, c1, c2, r2) on the basis (1, lx, ly, lx^2 + ly^2).

    Args:
        g: [n, S, 14 + F] gathered surfel rows.
        origin: [n, 2] pixel coordinates (x, y) of each tile's corner.
    """
    a, b, c = g[..., COL_A:COL_B], g[..., COL_B:COL_C], g[..., COL_C:COL_DET]  # [n, S, 3]
    x0, y0 = origin[:, 0, None, None], origin[:, 1, None, None]
    rows_c = torch.stack([c + a * x0 + b * y0, a, b, torch.zeros_like(a)], dim=-1)  # [n, S, 3, 4]
    mx, my = g[..., COL_MEAN2D] - origin[:, 0, None], g[..., COL_MEAN2D + 1] - origin[:, 1, None]
    row_r2 = torch.stack([2.0 * (mx * mx + my * my), -4.0 * mx, -4.0 * my, torch.full_like(mx, 2.0)], dim=-1)
    return torch.cat([rows_c, row_r2[:, :, None]], dim=2)


def _coefficients_vjp(d_coef: Tensor, g: Tensor, origin: Tensor) -> Tensor:
    """Gradient of :func:`coefficients` w.r.t. its geometry columns, [n, S, 14]."""
    x0, y0 = origin[:, 0, None, None], origin[:, 1, None, None]
    d_const, d_lx, d_ly = d_coef[:, :, :3, 0], d_coef[:, :, :3, 1], d_coef[:, :, :3, 2]  # [n, S, 3]
    d_a = d_const * x0 + d_lx
    d_b = d_const * y0 + d_ly
    mx, my = g[..., COL_MEAN2D] - origin[:, 0, None], g[..., COL_MEAN2D + 1] - origin[:, 1, None]
    d_r0 = d_coef[:, :, 3, 0]
    d_mx = 4.0 * (d_r0 * mx - d_coef[:, :, 3, 1])
    d_my = 4.0 * (d_r0 * my - d_coef[:, :, 3, 2])
    return torch.cat([d_a, d_b, d_const, torch.zeros_like(d_a[..., :1]), d_mx[..., None], d_my[..., None]], dim=-1)


class TileComposite(torch.autograd.Function):
    """Composites S surfels (front to back) into n tiles of P pixels.

    Inputs: g [n, S, 14 + F] gathered surfel rows (columns ``COL_*``), origin [n, 2]
    tile corners in pixels, t0 [n, P] transmittance before the list, basis [4, P]
    (:func:`pixel_basis`), intersection (bool, hbb1 depth rule vs centre depth).
    Outputs: chan [n, P, F], wsum [n, P], wz [n, P], z_median [n, P] (0 where none),
    has_median [n, P] bool, t_end [n, P]. Gradients flow to g and t0.
    """

    @staticmethod
    def forward(ctx, g, origin, t0, basis, intersection):
        coef = coefficients(g, origin)
        det, log_op, z_center, chan = g[..., COL_DET], g[..., COL_LOGOP], g[..., COL_ZC], g[..., COL_CHAN:]
        _, _, r2, r3, degenerate, inv = _geometry(coef, basis)
        use_r3 = r3 <= r2
        z = _depth(use_r3, det, inv, z_center) if intersection else z_center[..., None].expand_as(r3)
        e = torch.minimum(r3, r2, out=r3).mul_(-0.5).add_(log_op[..., None]).exp_()
        skip = (e < ALPHA_THRESHOLD).logical_or_(degenerate)
        alpha = e.clamp_max_(ALPHA_MAX).masked_fill_(skip, 0.0)
        one_m = 1.0 - alpha
        t_incl = torch.cumprod(one_m, dim=1).mul_(t0[:, None])
        t_excl = t_incl / one_m
        alpha.masked_fill_(t_incl <= T_STOP, 0.0)  # gsplat's early termination (exact, see module doc)
        w = alpha * t_excl
        out_chan = torch.bmm(w.transpose(1, 2), chan)
        wsum = w.sum(1)
        wz = (w * z).sum(1)
        cand = (alpha > 0).logical_and_(t_excl > T_MEDIAN)
        index = torch.arange(w.shape[1], device=w.device).view(1, -1, 1)
        last = torch.where(cand, index, -1).amax(1)  # [n, P]
        has = last >= 0
        z_med = torch.gather(z, 1, last.clamp_min(0)[:, None]).squeeze(1) * has
        t_end = t_incl[:, -1]
        ctx.intersection = intersection
        ctx.save_for_backward(g, origin, t0, basis, alpha, t_excl, t_end, last)
        ctx.mark_non_differentiable(has)
        return out_chan, wsum, wz, z_med, has, t_end

    @staticmethod
    def backward(ctx, g_chan, g_wsum, g_wz, g_zmed, _g_has, g_tend):
        g, origin, t0, basis, alpha, t_excl, t_end, last = ctx.saved_tensors
        det, z_center, chan = g[..., COL_DET], g[..., COL_ZC], g[..., COL_CHAN:]
        c0, c1, r2, r3, _, inv = _geometry(coefficients(g, origin), basis)
        use_r3 = r3 <= r2
        z = _depth(use_r3, det, inv, z_center) if ctx.intersection else z_center[..., None]
        w = alpha * t_excl
        # s = dL/dw per (surfel, pixel)
        s = torch.bmm(chan, g_chan.transpose(1, 2)).add_(g_wsum[:, None]).addcmul_(z, g_wz[:, None])
        cums = torch.cumsum(w * s, dim=1)
        total = cums[:, -1] + g_tend * t_end
        # dL/dalpha_i = T_i s_i - (sum_{k>i} w_k s_k + dL/dt_end t_end) / (1 - alpha_i);
        # times alpha = dL/d(log opacity - rho / 2) where alpha is not clamped (0 where skipped)
        grad_pre = cums.sub_(total[:, None]).div_(1.0 - alpha).addcmul_(t_excl, s).mul_(alpha)
        grad_pre.masked_fill_(alpha >= ALPHA_MAX, 0.0)
        d_log_op = grad_pre.sum(-1)
        d_rho = grad_pre.mul_(-0.5)
        d_geo = torch.empty(d_rho.shape[:2] + (4,) + d_rho.shape[2:], dtype=d_rho.dtype, device=d_rho.device)
        d_r3_inv = torch.where(use_r3, d_rho, 0.0).mul_(inv)  # dL/dr3 / c2, zero where r2 won
        torch.where(use_r3, d_rho.new_zeros(()), d_rho, out=d_geo[:, :, 3])
        k = (2.0 * inv).mul_(d_r3_inv)
        torch.mul(k, c0, out=d_geo[:, :, 0])
        torch.mul(k, c1, out=d_geo[:, :, 1])
        torch.mul(d_r3_inv, r3, out=d_geo[:, :, 2]).mul_(-2.0)
        d_z = w * g_wz[:, None]
        has = (last >= 0).to(d_z.dtype)
        d_z.scatter_add_(1, last.clamp_min(0)[:, None], (g_zmed * has)[:, None])
        d_det = None
        if ctx.intersection:  # z = det / c2 where the surfel kernel won, else the centre depth
            d_zc = torch.where(use_r3, 0.0, d_z).sum(-1)
            d_z_inv = d_z.masked_fill_(~use_r3, 0.0).mul_(inv)
            d_det = d_z_inv.sum(-1)
            d_geo[:, :, 2].sub_(d_z_inv.mul_(z))
        else:
            d_zc = d_z.sum(-1)
        d_geom = _coefficients_vjp(torch.matmul(d_geo, basis.transpose(0, 1)), g, origin)
        if d_det is not None:
            d_geom[..., COL_DET] = d_det
        d_chan = torch.bmm(w, g_chan)
        d_t0 = torch.where(t0 > 0, total / torch.where(t0 > 0, t0, 1.0), 0.0)
        d_g = torch.cat([d_geom, d_log_op[..., None], d_zc[..., None], d_chan], dim=-1)
        return d_g, None, d_t0, None, None
