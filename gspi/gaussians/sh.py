"""Real spherical harmonics for view-dependent Gaussian colour (degrees 0..3).

The constants and the basis order are the ones of the Inria 3DGS / hbb1 2DGS
code (``utils/sh_utils.py``) and of gsplat's ``_eval_sh_bases_fast``; the
colour convention is theirs too: ``rgb = max(SH(dir) + 0.5, 0)`` with
``dir = normalize(center - camera_center)``.

Hand-written rather than imported from gsplat because gsplat is an optional,
GPU-only dependency of this project.
"""

from __future__ import annotations

import torch
from torch import Tensor

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
MAX_SH_DEGREE = 3


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients per colour channel, ``(degree + 1) ** 2``."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be in 0..{MAX_SH_DEGREE}, got {degree}")
    return (degree + 1) ** 2


def sh_degree_from_bases(num_bases: int) -> int:
    """Inverse of :func:`num_sh_bases`; raises ``ValueError`` for 2, 3, 5, ..."""
    for degree in range(MAX_SH_DEGREE + 1):
        if num_sh_bases(degree) == num_bases:
            return degree
    raise ValueError(f"{num_bases} is not (d + 1)^2 for an SH degree d in 0..{MAX_SH_DEGREE}")


def rgb_to_sh(rgb: Tensor) -> Tensor:
    """DC coefficient whose constant colour is ``rgb``: ``(rgb - 0.5) / C0``."""
    return (rgb - 0.5) / SH_C0


def sh_to_rgb(sh_dc: Tensor) -> Tensor:
    """View-independent colour of a DC coefficient: ``0.5 + C0 * f_dc``."""
    return 0.5 + SH_C0 * sh_dc


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Real SH basis values in the Inria order.

    Args:
        degree: SH degree, 0..3.
        dirs: [..., 3] directions; normalised here.

    Returns:
        [..., (degree + 1) ** 2] basis values.
    """
    num_sh_bases(degree)  # validates the degree
    d = torch.nn.functional.normalize(dirs, dim=-1)
    x, y, z = d.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh(degree: int, sh: Tensor, dirs: Tensor) -> Tensor:
    """Evaluates real SH of ``degree`` in the Inria basis order.

    Args:
        degree: SH degree to use, 0..3; may be lower than ``sh`` holds.
        sh: coefficients, [..., K, 3] with K >= (degree + 1) ** 2.
        dirs: view directions, [..., 3]; normalised here.

    Returns:
        [..., 3] SH value (without the +0.5 offset).
    """
    k = num_sh_bases(degree)
    if sh.shape[-2] < k:
        raise ValueError(f"degree {degree} needs {k} coefficients, got {sh.shape[-2]}")
    basis = sh_basis(degree, dirs)  # [..., k]
    return (basis[..., None] * sh[..., :k, :]).sum(-2)


def sh_colors(degree: int, sh: Tensor, means: Tensor, camera_center: Tensor) -> Tensor:
    """Inria/2DGS view-dependent colour ``max(SH(dir) + 0.5, 0)``.

    Args:
        degree: SH degree to evaluate, 0..3.
        sh: coefficients, [N, K, 3].
        means: Gaussian centres in world space, [N, 3].
        camera_center: camera centre in world space, [3].

    Returns:
        [N, 3] linear colour as the renderer composites it (not clamped above).
    """
    dirs = means - camera_center
    return torch.clamp_min(eval_sh(degree, sh, dirs) + 0.5, 0.0)
