"""gsplat 1.5.3 CUDA backend of :func:`gspi.gaussians.rasterize.rasterize_2dgs`.

One call of ``gsplat.rasterization_2dgs`` with ``sh_degree=None`` and per-view
colours ``[C, N, D]`` packing ``[rgb, features, centre depth, surfel id + 1]``:

* colour, features and ``sum_i w_i z_i`` (centre depth, gsplat's convention) come
  out composited; expected depth = that sum / alpha;
* gsplat's ``render_median`` is "the last channel of the surfel at which the
  transmittance crosses 0.5", so with the id in the last channel it returns the
  median surfel's id per pixel (exact in float32 for N < 2^24). The median depth
  is then evaluated in torch at that surfel, as centre depth or with hbb1's
  per-pixel rule (ray-splat intersection depth where the surfel kernel wins the
  low-pass min, centre depth elsewhere), and stays differentiable;
* scales get a third column of 1.0 (gsplat's CUDA kernels ignore it; 0 would
  zero the normal in gsplat's torch reference).

gsplat's tile boxes are ``ceil(3.33 sigma)`` of the 1-sigma ellipse, so a
sub-pixel surfel may be cut at a tile border there (the torch backend never
cuts); expect differences only from such surfels and from float rounding.
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from gspi.gaussians.projection import project_surfels
from gspi.gaussians.render_output import RenderOutput

_MAX_EXACT_ID = 1 << 24


def _median_depth(
    ids: Tensor,  # [C, H, W] int64, 0 = none, else surfel index + 1
    ray_transforms: Tensor,  # [C, N, 3, 3]
    means2d: Tensor,  # [C, N, 2]
    depths: Tensor,  # [C, N]
    intersection: bool,
) -> Tensor:
    """[C, H, W, 1] depth of the median surfel of every pixel (0 where none).

    With ``intersection`` the depth follows hbb1: the ray-splat intersection z where
    the surfel kernel wins the low-pass min, the centre z where the filter wins.
    """
    n_cams, height, width = ids.shape
    idx = (ids - 1).clamp_min(0).reshape(n_cams, -1)  # [C, HW]
    z = torch.gather(depths, 1, idx)
    if intersection:
        m = torch.gather(ray_transforms.reshape(n_cams, -1, 9), 1, idx[..., None].expand(-1, -1, 9))
        m0, m1, m2 = m.reshape(n_cams, -1, 3, 3).unbind(-2)
        mean2d = torch.gather(means2d, 1, idx[..., None].expand(-1, -1, 2))
        ys, xs = torch.meshgrid(
            torch.arange(height, device=ids.device, dtype=m.dtype) + 0.5,
            torch.arange(width, device=ids.device, dtype=m.dtype) + 0.5,
            indexing="ij",
        )
        pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)[None]  # [1, HW, 2]
        cross = torch.linalg.cross(pix[..., :1] * m2 - m0, pix[..., 1:] * m2 - m1, dim=-1)
        c2 = torch.where(cross[..., 2] != 0, cross[..., 2], torch.ones_like(cross[..., 2]))
        rho3d = (cross[..., 0] ** 2 + cross[..., 1] ** 2) / c2**2
        rho2d = 2.0 * ((pix - mean2d) ** 2).sum(-1)
        det = (m0 * torch.linalg.cross(m1, m2, dim=-1)).sum(-1)
        z = torch.where(rho3d <= rho2d, det / c2, z)
    z = torch.where(ids.reshape(n_cams, -1) > 0, z, torch.zeros_like(z))
    return z.reshape(n_cams, height, width, 1)


def rasterize_gsplat(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 2]
    opacities: Tensor,  # [N]
    rgb: Optional[Tensor],  # [C, N, Dc] post-activation
    feats: Optional[Tensor],  # [C, N, Df]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    near_plane: float,
    far_plane: float,
    depth_point: str,
):
    """Renders with gsplat's CUDA rasterizer; returns a ``RenderOutput``.

    Args are those of :func:`gspi.gaussians.rasterize.rasterize_2dgs`, with colours
    already evaluated per view. The expected depth is centre-based whatever
    ``depth_point`` says (gsplat composites per-surfel values only).
    """
    from gsplat import rasterization_2dgs


    n_cams, n = viewmats.shape[0], means.shape[0]
    if n + 1 >= _MAX_EXACT_ID:
        raise ValueError(f"gsplat backend encodes surfel ids in float32; {n} surfels is too many")
    proj = project_surfels(means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane)
    ids = torch.arange(1, n + 1, device=means.device, dtype=means.dtype)
    chans = [t for t in (rgb, feats) if t is not None]
    chans += [proj.depths[..., None], ids.expand(n_cams, n)[..., None]]
    colors = torch.cat(chans, dim=-1)  # [C, N, D]
    scales3 = torch.cat([scales[:, :2], torch.ones_like(scales[:, :1])], dim=-1)
    render, alpha, normals, _, _, median, meta = rasterization_2dgs(
        means, quats, scales3, opacities, colors, viewmats, Ks, width, height,
        near_plane=near_plane, far_plane=far_plane, sh_degree=None, render_mode="RGB",
    )
    d_rgb = 0 if rgb is None else rgb.shape[-1]
    d_feat = 0 if feats is None else feats.shape[-1]
    o = d_rgb + d_feat
    depth_sum = render[..., o : o + 1]
    depth_expected = torch.where(alpha > 0, depth_sum / alpha.clamp_min(1e-10), torch.zeros_like(alpha))
    median_ids = median.detach()[..., 0].round().long()
    depth_median = _median_depth(
        median_ids, proj.ray_transforms, proj.means2d, proj.depths, depth_point == "intersection"
    )
    return RenderOutput(
        rgb=render[..., :d_rgb] if rgb is not None else None,
        features=render[..., d_rgb:o] if feats is not None else None,
        alpha=alpha,
        depth_expected=depth_expected,
        depth_median=depth_median,
        normals=normals,
        depth_point=depth_point,
        meta={"radii": meta["radii"], "means2d": meta["means2d"], "depths": meta["depths"]},
    )
