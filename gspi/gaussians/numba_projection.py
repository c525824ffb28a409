"""Compiled (numba) projection and SH colour of one view's surfels, with a hand-written backward.

For the numba backend this replaces, per camera, the few hundred small torch ops of
:func:`gspi.gaussians.projection.project_surfels`, :func:`gspi.gaussians.sh.sh_colors` and the
geometry columns of :func:`gspi.gaussians.torch_backend.surfel_table` (and their autograd
graph) by one loop over the surfels: at 5k surfels those ops were ~15 of a full step's ~40 ms
(docs/STAGE3.md), the arithmetic ~1 ms. The math is theirs, written out per surfel:

  ``R = rot(q / |q|)``, ``mean_c = V mean + t``, ``M = K [R_cw R_0 s_u, R_cw R_1 s_v, mean_c]``
  (rows m0, m1, m2: gsplat's ray transform), the normal ``R_2`` flipped to face the camera;
  the table row ``m1 x m2, m2 x m0, m0 x m1, m0 . (m1 x m2)``, the 2D centre of the dual conic
  ``diag(1, 1, -1)`` (``projection.conic_bounds``), ``log max(opacity, 1e-30)``, ``mean_c.z``;
  the colour ``max(SH(normalize(mean - camera)) + 0.5, 0)`` in the Inria basis (``sh.py``).

The backward follows the chain rule of the same expressions back to means, quats, scales,
opacities and SH coefficients (cross-product, dual-conic quotient, ``K^T``, ``R_cw^T``, the
quaternion-to-rotation derivative, the normalisations, the SH basis derivatives, as gsplat's
``Projection2DGSFused`` / ``spherical_harmonics`` backward kernels do), and, for Stage 0's
densification, gsplat's ``gradient_2dgs`` (``(dL/dM[0, 2], dL/dM[1, 2]) * M[2, 2]`` from the
table's geometry columns; ``gspi/recon/render.py``). The torch ops stay the reference: outputs
and gradients equal theirs (tests/test_numba_projection.py). Camera gradients (viewmats, Ks)
are not computed: callers that need them use the torch path.

Arithmetic is float64 inside; results and gradients come back in the inputs' dtype.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numba
import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from gspi.gaussians.composite import COL_CHAN
from gspi.gaussians.numba_jit import njit_cached, threads
from gspi.gaussians.sh import SH_C0, SH_C1, SH_C2, SH_C3, num_sh_bases

_NORM_EPS = 1e-12  # torch.nn.functional.normalize's eps
_LOG_OPACITY_MIN = 1e-30  # surfel_table's clamp before the log
_NO_SH = -1  # degree passed to the kernels when the colours are not SH


@njit_cached(inline="always")
def _rotation(qw, qx, qy, qz):
    """|q| and the rotation of q / max(|q|, eps) (projection.quat_to_rotmat), row-major."""
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / max(norm, _NORM_EPS)
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    rot = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
           2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
           2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    return norm, (w, x, y, z), rot


@njit_cached(inline="always")
def _ray_transform(means, scales, i, rot, view, cam_k, mc, tc, m):
    """Fills mean_c [3] and M = K [tcu, tcv, mean_c] [3, 3] of surfel i (projection.project_surfels);
    tc [3, 3] is scratch (columns R_cw R_0 s_u, R_cw R_1 s_v, mean_c)."""
    su, sv = float(scales[i, 0]), float(scales[i, 1])
    for r in range(3):
        mc[r] = view[r, 0] * means[i, 0] + view[r, 1] * means[i, 1] + view[r, 2] * means[i, 2] + view[r, 3]
        tc[r, 0] = (view[r, 0] * rot[0] + view[r, 1] * rot[3] + view[r, 2] * rot[6]) * su
        tc[r, 1] = (view[r, 0] * rot[1] + view[r, 1] * rot[4] + view[r, 2] * rot[7]) * sv
        tc[r, 2] = mc[r]
    for r in range(3):
        for c in range(3):
            m[r, c] = cam_k[r, 0] * tc[0, c] + cam_k[r, 1] * tc[1, c] + cam_k[r, 2] * tc[2, c]


@njit_cached(inline="always")
def _dual(m, a, b):
    """Dual-conic product a^T diag(1, 1, -1) b of rows a, b of m (projection.conic_bounds, r = 1)."""
    return m[a, 0] * m[b, 0] + m[a, 1] * m[b, 1] - m[a, 2] * m[b, 2]


@njit_cached(inline="always")
def _facing(view, rot, mc):
    """+1 where the surfel's normal R_2 faces the camera, else -1 (project_surfels' flip)."""
    dot = 0.0
    for r in range(3):
        dot += (view[r, 0] * rot[2] + view[r, 1] * rot[5] + view[r, 2] * rot[8]) * mc[r]
    return 1.0 if -dot > 0.0 else -1.0


@njit_cached(inline="always")
def _sh_basis(degree, x, y, z, out):
    """Real SH basis of degree 0..3 at the unit direction (x, y, z) into out[:(degree + 1)^2] (sh.sh_basis)."""
    out[0] = SH_C0
    if degree >= 1:
        out[1], out[2], out[3] = -SH_C1 * y, SH_C1 * z, -SH_C1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = SH_C2[0] * x * y
        out[5] = SH_C2[1] * y * z
        out[6] = SH_C2[2] * (2.0 * zz - xx - yy)
        out[7] = SH_C2[3] * x * z
        out[8] = SH_C2[4] * (xx - yy)
    if degree >= 3:
        out[9] = SH_C3[0] * y * (3.0 * xx - yy)
        out[10] = SH_C3[1] * x * y * z
        out[11] = SH_C3[2] * y * (4.0 * zz - xx - yy)
        out[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        out[13] = SH_C3[4] * x * (4.0 * zz - xx - yy)
        out[14] = SH_C3[5] * z * (xx - yy)
        out[15] = SH_C3[6] * x * (xx - 3.0 * yy)


@njit_cached(inline="always")
def _sh_basis_vjp(degree, x, y, z, g):
    """sum_k g[k] dB_k / d(x, y, z) for the basis of :func:`_sh_basis`."""
    gx = gy = gz = 0.0
    if degree >= 1:
        gx -= SH_C1 * g[3]
        gy -= SH_C1 * g[1]
        gz += SH_C1 * g[2]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        gx += SH_C2[0] * y * g[4] - 2.0 * SH_C2[2] * x * g[6] + SH_C2[3] * z * g[7] + 2.0 * SH_C2[4] * x * g[8]
        gy += SH_C2[0] * x * g[4] + SH_C2[1] * z * g[5] - 2.0 * SH_C2[2] * y * g[6] - 2.0 * SH_C2[4] * y * g[8]
        gz += SH_C2[1] * y * g[5] + 4.0 * SH_C2[2] * z * g[6] + SH_C2[3] * x * g[7]
    if degree >= 3:
        gx += (SH_C3[0] * 6.0 * x * y * g[9] + SH_C3[1] * y * z * g[10] - SH_C3[2] * 2.0 * x * y * g[11]
               - SH_C3[3] * 6.0 * x * z * g[12] + SH_C3[4] * (4.0 * zz - 3.0 * xx - yy) * g[13]
               + SH_C3[5] * 2.0 * x * z * g[14] + SH_C3[6] * (3.0 * xx - 3.0 * yy) * g[15])
        gy += (SH_C3[0] * (3.0 * xx - 3.0 * yy) * g[9] + SH_C3[1] * x * z * g[10]
               + SH_C3[2] * (4.0 * zz - xx - 3.0 * yy) * g[11] - SH_C3[3] * 6.0 * y * z * g[12]
               - SH_C3[4] * 2.0 * x * y * g[13] - SH_C3[5] * 2.0 * y * z * g[14] - SH_C3[6] * 6.0 * x * y * g[15])
        gz += (SH_C3[1] * x * y * g[10] + SH_C3[2] * 8.0 * y * z * g[11]
               + SH_C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g[12] + SH_C3[4] * 8.0 * x * z * g[13]
               + SH_C3[5] * (xx - yy) * g[14])
    return gx, gy, gz


@njit_cached(inline="always")
def _direction(means, i, center):
    """|mean - camera| and the unit view direction (normalize as torch does)."""
    vx, vy, vz = means[i, 0] - center[0], means[i, 1] - center[1], means[i, 2] - center[2]
    norm = math.sqrt(vx * vx + vy * vy + vz * vz)
    inv = 1.0 / max(norm, _NORM_EPS)
    return norm, vx * inv, vy * inv, vz * inv


_BLOCK = 256  # surfels per parallel task (scratch arrays are allocated once per task)
# The per-surfel kernels loop over their block themselves: called once per surfel with ~30
# array arguments, the calls cost ~18 % of the projection (50k surfels: 28.1 -> 23.0 ms fwd+bwd)


@njit_cached()
def _forward_block(start, stop, means, quats, scales, opacities, sh, degree, view, cam_k, center, width, height,
                   near, far, geo, rgb, normals, rt, radii, in_range, mc, tc, m, basis):
    for i in range(start, stop):
        _, _, rot = _rotation(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3])
        _ray_transform(means, scales, i, rot, view, cam_k, mc, tc, m)
        facing = _facing(view, rot, mc)
        for r in range(3):
            normals[i, r] = rot[3 * r + 2] * facing
            for c in range(3):
                rt[i, r, c] = m[r, c]
        c22 = _dual(m, 2, 2)
        bounded = c22 < 0.0
        c22s = c22 if bounded else -1.0
        cx, cy = _dual(m, 0, 2) / c22s, _dual(m, 1, 2) / c22s
        hx = math.sqrt(max(cx * cx - _dual(m, 0, 0) / c22s, 0.0))
        hy = math.sqrt(max(cy * cy - _dual(m, 1, 1) / c22s, 0.0))
        depth = mc[2]
        rx, ry = math.ceil(3.33 * math.sqrt(max(hx * hx, 1e-4))), math.ceil(3.33 * math.sqrt(max(hy * hy, 1e-4)))
        on_image = cx + rx > 0 and cx - rx < width and cy + ry > 0 and cy - ry < height
        in_range[i] = near < depth < far
        keep = in_range[i] and on_image and bounded
        radii[i, 0], radii[i, 1] = (rx, ry) if keep else (0, 0)
        # rows of M: a = m1 x m2, b = m2 x m0, c = m0 x m1, det = m0 . a
        det = 0.0
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            a_j = m[1, j1] * m[2, j2] - m[1, j2] * m[2, j1]
            det += m[0, j] * a_j
            geo[i, j] = a_j
            geo[i, 3 + j] = m[2, j1] * m[0, j2] - m[2, j2] * m[0, j1]
            geo[i, 6 + j] = m[0, j1] * m[1, j2] - m[0, j2] * m[1, j1]
        geo[i, 9] = det
        geo[i, 10], geo[i, 11] = cx, cy
        geo[i, 12] = math.log(max(float(opacities[i]), _LOG_OPACITY_MIN))
        geo[i, 13] = depth
        if degree >= 0:
            _, dx, dy, dz = _direction(means, i, center)
            _sh_basis(degree, dx, dy, dz, basis)
            for ch in range(3):
                v = 0.5
                for k in range((degree + 1) * (degree + 1)):
                    v += basis[k] * sh[i, k, ch]
                rgb[i, ch] = max(v, 0.0)


@njit_cached(parallel=True)
def _forward(means, quats, scales, opacities, sh, degree, view, cam_k, center, size, planes,
             geo, rgb, normals, rt, radii, in_range):
    n = means.shape[0]
    for block in numba.prange((n + _BLOCK - 1) // _BLOCK):
        mc, tc, m, basis = np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty(16)
        _forward_block(block * _BLOCK, min(n, (block + 1) * _BLOCK), means, quats, scales, opacities, sh, degree,
                       view, cam_k, center, size[0], size[1], planes[0], planes[1], geo, rgb, normals, rt, radii,
                       in_range, mc, tc, m, basis)


@njit_cached(inline="always")
def _cross_vjp(g, p, q, gp, gq):
    """u = p x q: adds dL/dp = q x g to gp and dL/dq = g x p to gq (3-vectors)."""
    gp[0] += q[1] * g[2] - q[2] * g[1]
    gp[1] += q[2] * g[0] - q[0] * g[2]
    gp[2] += q[0] * g[1] - q[1] * g[0]
    gq[0] += g[1] * p[2] - g[2] * p[1]
    gq[1] += g[2] * p[0] - g[0] * p[2]
    gq[2] += g[0] * p[1] - g[1] * p[0]


@njit_cached(inline="always")
def _rotation_vjp(q, g):
    """dL/d(w, x, y, z) of the unit quaternion from dL/dR (row-major 9, :func:`_rotation`)."""
    w, x, y, z = q
    dw = 2.0 * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7])
    dx = 2.0 * (y * g[1] + z * g[2] + y * g[3] - 2.0 * x * g[4] - w * g[5] + z * g[6] + w * g[7] - 2.0 * x * g[8])
    dy = 2.0 * (-2.0 * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - 2.0 * y * g[8])
    dz = 2.0 * (-2.0 * z * g[0] - w * g[1] + x * g[2] + w * g[3] - 2.0 * z * g[4] + y * g[5] + x * g[6] + y * g[7])
    return dw, dx, dy, dz


@njit_cached()
def _backward_block(start, stop, means, quats, scales, opacities, sh, degree, view, cam_k, center,
                    g_geo, g_rgb, g_normals, want_delta, g_means, g_quats, g_scales, g_opacities, g_sh, g_delta,
                    mc, tc, m, gm, ga, gtc, grot, basis, gbasis):
    for i in range(start, stop):
        qnorm, qn, rot = _rotation(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3])
        _ray_transform(means, scales, i, rot, view, cam_k, mc, tc, m)
        facing = _facing(view, rot, mc)
        gm[:] = 0.0  # dL/dM from a, b, c, det (the rows the densification shift enters)
        # det = m0 . a with a = m1 x m2: dL/dm0 += g_det a, and dL/da gains g_det m0
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            gm[0, j] += g_geo[i, 9] * (m[1, j1] * m[2, j2] - m[1, j2] * m[2, j1])
            ga[j] = g_geo[i, j] + g_geo[i, 9] * m[0, j]
        _cross_vjp(ga, m[1], m[2], gm[1], gm[2])
        _cross_vjp(g_geo[i, 3:6], m[2], m[0], gm[2], gm[0])
        _cross_vjp(g_geo[i, 6:9], m[0], m[1], gm[0], gm[1])
        if want_delta:
            g_delta[i, 0] = gm[0, 2] * m[2, 2]
            g_delta[i, 1] = gm[1, 2] * m[2, 2]
        # the 2D centre (d02 / c22, d12 / c22); c22 is a constant -1 where the conic is unbounded
        c22 = _dual(m, 2, 2)
        bounded = c22 < 0.0
        c22s = c22 if bounded else -1.0
        d02, d12 = _dual(m, 0, 2), _dual(m, 1, 2)
        gd02, gd12 = g_geo[i, 10] / c22s, g_geo[i, 11] / c22s
        gc22 = -(g_geo[i, 10] * d02 + g_geo[i, 11] * d12) / (c22s * c22s) if bounded else 0.0
        for j in range(3):
            sign = -1.0 if j == 2 else 1.0
            gm[0, j] += gd02 * sign * m[2, j]
            gm[1, j] += gd12 * sign * m[2, j]
            gm[2, j] += sign * (gd02 * m[0, j] + gd12 * m[1, j] + 2.0 * gc22 * m[2, j])
        # M = K [tcu, tcv, mean_c]: dL/d columns = K^T dL/dM; depth = mean_c.z
        for r in range(3):
            for c in range(3):
                gtc[r, c] = cam_k[0, r] * gm[0, c] + cam_k[1, r] * gm[1, c] + cam_k[2, r] * gm[2, c]
        gtc[2, 2] += g_geo[i, 13]
        # world: mean_c = V mean + t, tc_u = V R_0 s_u, tc_v = V R_1 s_v (dL/dx = V^T dL/dx_c)
        grot[:] = 0.0
        su, sv = float(scales[i, 0]), float(scales[i, 1])
        gsu = gsv = 0.0
        for j in range(3):
            gmean = view[0, j] * gtc[0, 2] + view[1, j] * gtc[1, 2] + view[2, j] * gtc[2, 2]
            gtu = view[0, j] * gtc[0, 0] + view[1, j] * gtc[1, 0] + view[2, j] * gtc[2, 0]
            gtv = view[0, j] * gtc[0, 1] + view[1, j] * gtc[1, 1] + view[2, j] * gtc[2, 1]
            g_means[i, j] = gmean
            grot[3 * j] += gtu * su
            grot[3 * j + 1] += gtv * sv
            grot[3 * j + 2] += g_normals[i, j] * facing
            gsu += gtu * rot[3 * j]
            gsv += gtv * rot[3 * j + 1]
        g_scales[i, 0], g_scales[i, 1] = gsu, gsv
        # unit quaternion, then q / max(|q|, eps)
        gw, gx, gy, gz = _rotation_vjp(qn, grot)
        if qnorm > _NORM_EPS:
            dot = qn[0] * gw + qn[1] * gx + qn[2] * gy + qn[3] * gz
            g_quats[i, 0] = (gw - qn[0] * dot) / qnorm
            g_quats[i, 1] = (gx - qn[1] * dot) / qnorm
            g_quats[i, 2] = (gy - qn[2] * dot) / qnorm
            g_quats[i, 3] = (gz - qn[3] * dot) / qnorm
        else:
            g_quats[i, 0], g_quats[i, 1] = gw / _NORM_EPS, gx / _NORM_EPS
            g_quats[i, 2], g_quats[i, 3] = gy / _NORM_EPS, gz / _NORM_EPS
        op = float(opacities[i])
        g_opacities[i] = g_geo[i, 12] / op if op >= _LOG_OPACITY_MIN else 0.0
        if degree >= 0:
            gbasis[:] = 0.0
            vnorm, dx, dy, dz = _direction(means, i, center)
            _sh_basis(degree, dx, dy, dz, basis)
            nb = (degree + 1) * (degree + 1)
            for ch in range(3):
                # clamp_min(v, 0) passes the gradient where v >= 0; rgb = max(v, 0) >= 0 always, so
                # recompute the sign from the pre-clamp value
                v = 0.5
                for k in range(nb):
                    v += basis[k] * sh[i, k, ch]
                g = g_rgb[i, ch] if v >= 0.0 else 0.0
                for k in range(nb):
                    g_sh[i, k, ch] = basis[k] * g
                    gbasis[k] += sh[i, k, ch] * g
            ex, ey, ez = _sh_basis_vjp(degree, dx, dy, dz, gbasis)
            inv = 1.0 / max(vnorm, _NORM_EPS)
            if vnorm > _NORM_EPS:
                dot = dx * ex + dy * ey + dz * ez
                ex, ey, ez = (ex - dx * dot) * inv, (ey - dy * dot) * inv, (ez - dz * dot) * inv
            else:
                ex, ey, ez = ex * inv, ey * inv, ez * inv
            g_means[i, 0] += ex
            g_means[i, 1] += ey
            g_means[i, 2] += ez


@njit_cached(parallel=True)
def _backward(means, quats, scales, opacities, sh, degree, view, cam_k, center,
              g_geo, g_rgb, g_normals, want_delta,
              g_means, g_quats, g_scales, g_opacities, g_sh, g_delta):
    n = means.shape[0]
    for block in numba.prange((n + _BLOCK - 1) // _BLOCK):
        mc, tc, m, gm = np.empty(3), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
        ga, gtc, grot, basis, gbasis = np.empty(3), np.empty((3, 3)), np.empty(9), np.empty(16), np.empty(16)
        _backward_block(block * _BLOCK, min(n, (block + 1) * _BLOCK), means, quats, scales, opacities, sh, degree,
                        view, cam_k, center, g_geo, g_rgb, g_normals, want_delta, g_means, g_quats, g_scales,
                        g_opacities, g_sh, g_delta, mc, tc, m, gm, ga, gtc, grot, basis, gbasis)


def _array(t: Optional[Tensor], shape=None) -> np.ndarray:
    if t is None:
        return np.zeros(shape)
    return t.detach().contiguous().numpy()


@dataclass
class ViewSurfels:
    """One camera's surfels as the compositor needs them (:func:`project_view`).

    Attributes:
        geometry: [N, 14] the table's geometry columns (``torch_backend.surfel_table``):
            m1 x m2, m2 x m0, m0 x m1, det M, means2d, log opacity, centre depth; differentiable.
        rgb: [N, 3] view-dependent SH colour, or None when no SH was given; differentiable.
        normals: [N, 3] world-space normals facing the camera; differentiable.
        ray_transforms: [N, 3, 3] M (detached: for ``tiles.pixel_bounds``).
        radii: [N, 2] int32 gsplat radii (0 = culled), as ``project_surfels``.
        in_range: [N] bool, centre depth strictly between the near and far planes.
    """

    geometry: Tensor
    rgb: Optional[Tensor]
    normals: Tensor
    ray_transforms: Tensor
    radii: Tensor
    in_range: Tensor

    @property
    def means2d(self) -> Tensor:
        return self.geometry[:, 10:12]

    @property
    def depths(self) -> Tensor:
        return self.geometry[:, 13]


class NumbaViewProjection(torch.autograd.Function):
    """Projection + SH colour of one view (module docstring); differentiable w.r.t. means,
    quats, scales, opacities, sh and the densification shift ``delta``."""

    @staticmethod
    def forward(ctx, means, quats, scales, opacities, sh, delta, viewmat, cam_k, options):
        degree, width, height, near, far = options
        n, dtype = means.shape[0], means.dtype
        view = _array(viewmat).astype(np.float64)
        k_np = _array(cam_k).astype(np.float64)
        center = np.linalg.inv(view)[:3, 3].copy()
        arrays = [_array(t) for t in (means, quats, scales, opacities)]
        sh_np = _array(sh) if sh is not None else np.zeros((n, 1, 3), arrays[0].dtype)
        np_dtype = arrays[0].dtype
        geo = np.empty((n, COL_CHAN), np_dtype)
        rgb = np.empty((n, 3), np_dtype)
        normals = np.empty((n, 3), np_dtype)
        rt = np.empty((n, 3, 3), np_dtype)
        radii = np.empty((n, 2), np.int32)
        in_range = np.empty(n, np.bool_)
        numba.set_num_threads(threads())
        _forward(*arrays, sh_np, degree, view, k_np, center, (width, height), (float(near), float(far)),
                 geo, rgb, normals, rt, radii, in_range)
        ctx.options = degree, view, k_np, center, sh is not None, delta is not None
        ctx.save_for_backward(means, quats, scales, opacities, sh)
        outs = [torch.from_numpy(a) for a in (geo, rgb, normals, rt, radii, in_range)]
        ctx.mark_non_differentiable(*outs[3:])
        if sh is None:
            outs[1] = outs[1][:, :0]
        return tuple(o.to(dtype) if o.is_floating_point() else o for o in outs)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_geo, g_rgb, g_normals, _rt, _radii, _in_range):
        degree, view, k_np, center, has_sh, has_delta = ctx.options
        means, quats, scales, opacities, sh = ctx.saved_tensors
        n = means.shape[0]
        arrays = [_array(t) for t in (means, quats, scales, opacities)]
        sh_np = _array(sh) if has_sh else np.zeros((n, 1, 3), arrays[0].dtype)
        grads_in = [np.zeros(shape) if g is None else g.detach().to(torch.float64).contiguous().numpy()
                    for g, shape in ((g_geo, (n, COL_CHAN)), (g_rgb, (n, 3)), (g_normals, (n, 3)))]
        if not has_sh or grads_in[1].shape[1] != 3:
            grads_in[1] = np.zeros((n, 3))
        g_means, g_quats = np.empty((n, 3)), np.empty((n, 4))
        g_scales, g_opacities = np.zeros((n, scales.shape[1])), np.empty(n)
        # each SH gradient is written once (no sum), so writing it in the inputs' dtype rounds as
        # the float64 buffer's conversion did, without the [N, K, 3] float64 buffer and copy
        g_sh, g_delta = np.zeros(sh_np.shape, sh_np.dtype), np.zeros((n, 2))
        numba.set_num_threads(threads())
        _backward(*arrays, sh_np, degree, view, k_np, center, *grads_in, has_delta,
                  g_means, g_quats, g_scales, g_opacities, g_sh, g_delta)
        dtype = means.dtype
        out = [torch.from_numpy(a).to(dtype) for a in (g_means, g_quats, g_scales, g_opacities)]
        return (*out, torch.from_numpy(g_sh).to(dtype) if has_sh else None,
                torch.from_numpy(g_delta).to(dtype) if has_delta else None, None, None, None)


def project_view(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 2] (or [N, 3], third ignored)
    opacities: Tensor,  # [N]
    viewmat: Tensor,  # [4, 4]
    cam_k: Tensor,  # [3, 3]
    width: int,
    height: int,
    *,
    sh: Optional[Tensor] = None,  # [N, K, 3]
    sh_degree: Optional[int] = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    delta: Optional[Tensor] = None,  # [N, 2]
) -> ViewSurfels:
    """One camera's :class:`ViewSurfels`, compiled (CPU float32 / float64 tensors).

    ``sh`` with ``sh_degree`` adds the SH colour; ``delta`` (zeros that require grad) receives
    gsplat's ``gradient_2dgs`` as its gradient (``gspi/recon/render.py``).
    """
    if means.device.type != "cpu" or means.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"the numba projection runs on CPU float32 / float64 tensors, got "
                         f"{means.dtype} on {means.device.type}")
    if (sh is None) != (sh_degree is None):
        raise ValueError("give sh and sh_degree together (or neither)")
    degree = _NO_SH
    if sh is not None:
        degree = int(sh_degree)
        if sh.dim() != 3 or sh.shape[0] != means.shape[0] or sh.shape[1] < num_sh_bases(degree) or sh.shape[2] != 3:
            raise ValueError(f"SH degree {degree} needs sh [N, >= {num_sh_bases(degree)}, 3], got {tuple(sh.shape)}")
    scales = scales[:, :2]
    inputs = [t.to(means.dtype) for t in (quats, scales, opacities)]
    options = (degree, int(width), int(height), float(near_plane), float(far_plane))
    geo, rgb, normals, rt, radii, in_range = NumbaViewProjection.apply(
        means, *inputs, None if sh is None else sh.to(means.dtype), delta, viewmat, cam_k, options)
    return ViewSurfels(geo, rgb if sh is not None else None, normals, rt, radii, in_range)
