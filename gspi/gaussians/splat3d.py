"""3D Gaussian splats (the official graphdeco-inria/gaussian-splatting PLY) as 2DGS surfels.

Most Gaussian assets on disk are 3DGS files: ``x y z nx ny nz f_dc_0..2 f_rest_* opacity
scale_0 scale_1 scale_2 rot_0..3`` (log scales, inverse-sigmoid opacity, quaternion w x y z).
``flatten_3dgs`` turns each 3D Gaussian into the surfel of its two largest axes:

* the rotation's columns are sorted by their scale; the two largest axes span the surfel (its
  tangents, in decreasing scale), the smallest becomes its normal (the tangents' cross product,
  so the frame stays right-handed);
* the two largest log scales are kept, the smallest is dropped;
* position, opacity and every SH coefficient are kept unchanged.

What is lost: the thickness along the smallest axis (a 3DGS blob that is not flat renders
thinner, and its opacity integrates over a plane instead of a volume), and for near-isotropic
Gaussians the choice of normal is arbitrary (``info["isotropic_fraction"]`` counts those whose
smallest scale is more than half the middle one). docs/DATA.md "3DGS input".
"""
from __future__ import annotations

import torch
from torch import Tensor

from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.projection import quat_to_rotmat

ISOTROPIC_RATIO = 0.5  # smallest / middle scale above this: the surfel's normal is ill-defined


def rotmat_to_quat(rot: Tensor) -> Tensor:
    """[N, 3, 3] rotations -> [N, 4] unit quaternions (w, x, y, z), kornia's conversion."""
    from kornia.geometry.conversions import rotation_matrix_to_quaternion

    return rotation_matrix_to_quaternion(rot.contiguous())


def flatten_3dgs(means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                 sh_dc: Tensor, sh_rest: Tensor) -> tuple[Gaussians2D, dict]:
    """(surfels, info) from raw 3DGS parameters (log_scales [N, 3]); see the module docstring."""
    if log_scales.shape[-1] != 3:
        raise ValueError(f"3DGS log scales must be [N, 3], got {tuple(log_scales.shape)}")
    rot = quat_to_rotmat(quats.double())                       # [N, 3, 3], columns = axes
    order = torch.argsort(log_scales.double(), dim=1, descending=True)  # largest first
    axes = torch.gather(rot, 2, order[:, None, :].expand(-1, 3, -1))
    tangent_u, tangent_v = axes[..., 0], axes[..., 1]
    normal = torch.linalg.cross(tangent_u, tangent_v)          # right-handed: (u, v, u x v)
    frame = torch.stack([tangent_u, tangent_v, normal], dim=-1)
    sorted_scales = torch.gather(log_scales, 1, order)
    surfels = Gaussians2D(means=means.float(), quats=rotmat_to_quat(frame).float(),
                          log_scales=sorted_scales[:, :2].contiguous().float(),
                          opacity_logits=opacity_logits.float(), sh_dc=sh_dc.float(), sh_rest=sh_rest.float())
    ratio = torch.exp(sorted_scales[:, 2] - sorted_scales[:, 1])
    info = {"source_format": "3dgs", "rule": "two largest axes span the surfel, the smallest is its normal",
            "num_gaussians": int(len(means)),
            "isotropic_fraction": float((ratio > ISOTROPIC_RATIO).float().mean()) if len(means) else 0.0,
            "median_thickness_ratio": float(ratio.median()) if len(means) else 0.0}
    return surfels, info


def thicken_surfels(surfels: Gaussians2D, log_thickness: float, *, normal_axis: int = 2
                    ) -> tuple[Tensor, Tensor]:
    """(quats [N, 4], log_scales [N, 3]) of 3D Gaussians made from surfels by giving them the
    thickness ``exp(log_thickness)`` along their normal, stored as 3DGS axis ``normal_axis``
    (0, 1 or 2: the official files put no axis order on the scales)."""
    rot = quat_to_rotmat(surfels.quats.double())
    cols = [rot[..., 0], rot[..., 1]]
    cols.insert(normal_axis, rot[..., 2])
    frame = torch.stack(cols, dim=-1)
    if torch.linalg.det(frame).lt(0).any():  # keep a proper rotation: flip the normal column
        sign = torch.ones(3, dtype=frame.dtype)
        sign[normal_axis] = -1.0
        frame = torch.where(torch.linalg.det(frame)[:, None, None] < 0, frame * sign, frame)
    scales = [surfels.log_scales[:, 0], surfels.log_scales[:, 1]]
    scales.insert(normal_axis, torch.full_like(surfels.log_scales[:, 0], float(log_thickness)))
    return rotmat_to_quat(frame).float(), torch.stack(scales, dim=1).float()
