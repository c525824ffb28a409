"""Projection of 2D Gaussian surfels into pinhole cameras (2DGS, Huang et al. 2024).

Pure-torch port of gsplat's ``fully_fused_projection_2dgs`` (CUDA kernel
``Projection2DGSFused.cu`` and its reference ``_torch_impl_2dgs.py``), kept here
because gsplat's rasterizer is CUDA-only and this project must run on CPU.

Conventions (gsplat / OpenCV): ``viewmats`` are world-to-camera [C, 4, 4] with
x right, y down, z forward; ``Ks`` are pixel intrinsics [C, 3, 3] with pixel
centres at integer + 0.5; quaternions are (w, x, y, z).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices of (w, x, y, z) quaternions (normalised here).

    Args:
        quats: [..., 4] quaternions, need not be unit length.

    Returns:
        [..., 3, 3] rotations; column 0/1 are the surfel tangents, column 2 its normal.
    """
    w, x, y, z = F.normalize(quats, dim=-1).unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )
    return torch.stack(rows, dim=-1).reshape(quats.shape[:-1] + (3, 3))


@dataclass
class SurfelProjection:
    """Per-camera, per-surfel quantities of the 2DGS projection (gsplat layout).

    Attributes:
        ray_transforms: [C, N, 3, 3] rows M0, M1, M2 of ``K @ [s_u t_u, s_v t_v, mean_cam]``
            (gsplat's ``ray_transforms``): maps surfel-plane (u, v, 1) to homogeneous pixels.
        means2d: [C, N, 2] pixel centre of the projected 1-sigma ellipse (gsplat's
            ``means2d``; equals the projected mean for a fronto-parallel surfel). The
            screen-space low-pass filter is centred here.
        depths: [C, N] camera-space z of the surfel centre (used for sorting).
        normals: [C, N, 3] WORLD-space unit normal, flipped to face the camera.
        radii: [C, N, 2] int32 gsplat radii ``ceil(3.33 * 1-sigma half extent)``; 0 = culled
            (centre outside (near, far), degenerate, or box outside the image).
    """

    ray_transforms: Tensor
    means2d: Tensor
    depths: Tensor
    normals: Tensor
    radii: Tensor


def conic_bounds(ray_transforms: Tensor, radius_uv: Tensor | float) -> tuple[Tensor, Tensor, Tensor]:
    """Centre and half extents of the projected surfel disc ``u^2 + v^2 <= r^2``.

    Uses the dual conic ``diag(r^2, r^2, -1)`` mapped by the ray transform, the
    2DGS paper's bounding-box construction (gsplat uses r = 1).

    Args:
        ray_transforms: [..., 3, 3] rows M0, M1, M2.
        radius_uv: radius r of the disc in surfel units (sigmas), scalar or [...].

    Returns:
        centre [..., 2], half extents [..., 2] (pixels), and a bool mask [...] that is
        False where the projection is not a bounded ellipse (disc crossing the camera
        plane or degenerate); centre and extents are finite but meaningless there.
    """
    r2 = torch.as_tensor(radius_uv, dtype=ray_transforms.dtype, device=ray_transforms.device) ** 2
    m0, m1, m2 = ray_transforms.unbind(-2)

    def dual(a: Tensor, b: Tensor) -> Tensor:
        return r2 * (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]) - a[..., 2] * b[..., 2]

    c22 = dual(m2, m2)
    bounded = c22 < 0
    c22_safe = torch.where(bounded, c22, -torch.ones_like(c22))
    center = torch.stack([dual(m0, m2), dual(m1, m2)], dim=-1) / c22_safe[..., None]
    diag = torch.stack([dual(m0, m0), dual(m1, m1)], dim=-1) / c22_safe[..., None]
    half = torch.sqrt(torch.clamp_min(center * center - diag, 0.0))
    return center, half, bounded


def project_surfels(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 2] or [N, 3] (third ignored)
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
) -> SurfelProjection:
    """Projects surfels into C cameras (differentiable, pure torch).

    Args:
        means: world-space centres, [N, 3].
        quats: (w, x, y, z) rotations, [N, 4], need not be normalised.
        scales: activated tangent scales (world units), [N, 2]; a third column is ignored
            like gsplat's CUDA kernel does.
        viewmats: world-to-camera, [C, 4, 4], OpenCV axes.
        Ks: pixel intrinsics, [C, 3, 3].
        width: image width in pixels.
        height: image height in pixels.
        near_plane: surfels with centre z <= near_plane are culled.
        far_plane: surfels with centre z >= far_plane are culled.

    Returns:
        :class:`SurfelProjection` with C x N entries.
    """
    rot = quat_to_rotmat(quats)  # [N, 3, 3]
    R_cw, t_cw = viewmats[:, :3, :3], viewmats[:, :3, 3]
    means_c = torch.einsum("cij,nj->cni", R_cw, means) + t_cw[:, None, :]  # [C, N, 3]
    tangents_w = rot[..., :2] * scales[:, None, :2]  # [N, 3, 2] columns s_u t_u, s_v t_v
    tangents_c = torch.einsum("cij,njk->cnik", R_cw, tangents_w)  # [C, N, 3, 2]
    wh = torch.cat([tangents_c, means_c[..., None]], dim=-1)  # [C, N, 3, 3]
    ray_transforms = torch.einsum("cij,cnjk->cnik", Ks, wh)

    normals_c = torch.einsum("cij,nj->cni", R_cw, rot[..., 2])
    facing = (-(normals_c * means_c).sum(-1, keepdim=True) > 0).to(means.dtype) * 2 - 1
    normals_w = rot[None, :, :, 2] * facing  # flip in world = flip in camera

    means2d, half, bounded = conic_bounds(ray_transforms, 1.0)
    depths = means_c[..., 2]
    radii = torch.ceil(3.33 * torch.sqrt(torch.clamp_min(half.detach() ** 2, 1e-4)))
    w_h = torch.tensor([width, height], dtype=radii.dtype, device=radii.device)
    on_image = ((means2d.detach() + radii > 0) & (means2d.detach() - radii < w_h)).all(-1)
    keep = (depths > near_plane) & (depths < far_plane) & on_image & bounded
    radii = torch.where(keep[..., None], radii, torch.zeros_like(radii)).to(torch.int32)
    return SurfelProjection(ray_transforms, means2d, depths, normals_w, radii)
