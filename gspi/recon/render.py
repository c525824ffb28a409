"""Training-time rendering with gsplat's 2DGS densification gradient.

``rasterize_2dgs`` (gspi/gaussians) returns ``meta["means2d"]``, but there the 2D centre
only feeds the screen-space low-pass filter, so its gradient is ~0 for surfels larger than
a pixel: not the signal the 3DGS/2DGS densification rule thresholds. gsplat's 2DGS
rasterizer exposes instead ``meta["gradient_2dgs"]``, a zero [C, N, 2] tensor whose
gradient its CUDA backward sets to ``(dL/dM[0, 2] * z, dL/dM[1, 2] * z)``: the loss
gradient of a screen-space translation of the splat (M = ray transform, column 2 =
``K @ mean_cam``, z = its depth), as hbb1's 2DGS does. The tile rasterizer (torch or numba
compositing) has no such hook, so :func:`render_views` projects the surfels itself and
adds ``delta * z`` to that column (zero in value, hence the forward is unchanged):
autograd then gives ``delta.grad`` equal to gsplat's ``gradient_2dgs``, which
``gsplat.strategy.DefaultStrategy(key_for_gradient="gradient_2dgs")`` consumes.
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from gspi.gaussians.projection import project_surfels
from gspi.gaussians.rasterize import RenderOutput, tile_backend, view_colors
from gspi.gaussians.torch_backend import rasterize_view


def render_views(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 2] (or [N, 3], third ignored)
    opacities: Tensor,  # [N]
    sh: Tensor,  # [N, K, 3]
    sh_degree: int,
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    backgrounds: Optional[Tensor] = None,  # [C, 3]
    densify_grad: bool = False,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    tile_size: int = 8,
    backend: str = "auto",
) -> RenderOutput:
    """Renders activated surfels like ``rasterize_2dgs`` with a tile backend.

    ``backend``: "auto" (numba on CPU when it imports, else torch), "numba" or "torch"
    (:func:`gspi.gaussians.rasterize.tile_backend`; there is no gsplat path here).

    With ``densify_grad`` the output's ``meta`` carries gsplat's training-info keys:
    ``gradient_2dgs`` ([C, N, 2] zeros that require grad; see the module docstring),
    ``radii`` [C, N, 2], ``means2d``, ``depths``, ``width``, ``height``, ``n_cameras``,
    ``gaussian_ids`` (None: not packed).
    """
    composite = tile_backend(backend, means.device)
    if composite == "numba" and not (viewmats.requires_grad or Ks.requires_grad):
        return _render_views_numba(means, quats, scales, opacities, sh, sh_degree, viewmats, Ks, width, height,
                                   backgrounds=backgrounds, densify_grad=densify_grad, near_plane=near_plane,
                                   far_plane=far_plane, tile_size=tile_size)
    proj = project_surfels(means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane)
    rt = proj.ray_transforms  # [C, N, 3, 3], column 2 = K @ mean_cam
    delta = None
    if densify_grad:
        delta = torch.zeros(rt.shape[:2] + (2,), dtype=rt.dtype, device=rt.device, requires_grad=True)
        z = rt[..., 2, 2].detach()
        shift = torch.stack([delta[..., 0] * z, delta[..., 1] * z, torch.zeros_like(z)], dim=-1)
        rt = torch.cat([rt[..., :2], (rt[..., 2] + shift)[..., None]], dim=-1)
    rgb = view_colors(sh, means, viewmats, sh_degree)  # [C, N, 3]
    images = []
    for c in range(len(viewmats)):
        in_range = (proj.depths[c] > near_plane) & (proj.depths[c] < far_plane)
        chans = torch.cat([rgb[c], proj.normals[c]], dim=-1)
        images.append(rasterize_view(rt[c], proj.means2d[c], proj.depths[c], opacities, chans, in_range,
                                     width, height, tile_size=tile_size, intersection_depth=True,
                                     composite=composite))
    meta = {"radii": proj.radii, "means2d": proj.means2d, "depths": proj.depths}
    return _render_output(torch.stack(images), backgrounds, meta, delta, width, height)


def _render_views_numba(means, quats, scales, opacities, sh, sh_degree, viewmats, Ks, width, height, *,
                        backgrounds, densify_grad, near_plane, far_plane, tile_size) -> RenderOutput:
    """:func:`render_views` through the compiled projection (``numba_projection.project_view``,
    whose ``delta`` input receives gradient_2dgs directly) and the compiled compositing."""
    from gspi.gaussians.numba_projection import project_view
    from gspi.gaussians.torch_backend import padded_table, rasterize_table

    delta = None
    if densify_grad:
        delta = torch.zeros(len(viewmats), means.shape[0], 2, dtype=means.dtype, device=means.device,
                            requires_grad=True)
    images, views = [], []
    for c in range(len(viewmats)):
        view = project_view(means, quats, scales, opacities, viewmats[c], Ks[c], width, height, sh=sh,
                            sh_degree=sh_degree, near_plane=near_plane, far_plane=far_plane,
                            delta=None if delta is None else delta[c])
        table = padded_table(torch.cat([view.geometry, view.rgb, view.normals], dim=-1))
        images.append(rasterize_table(table, view.ray_transforms, opacities, view.in_range, width, height,
                                      tile_size=tile_size, intersection_depth=True, composite="numba"))
        views.append(view)
    meta = {"radii": torch.stack([v.radii for v in views]), "means2d": torch.stack([v.means2d for v in views]),
            "depths": torch.stack([v.depths for v in views])}
    return _render_output(torch.stack(images), backgrounds, meta, delta, width, height)


def _render_output(img: Tensor, backgrounds: Optional[Tensor], meta: dict, delta: Optional[Tensor],
                   width: int, height: int) -> RenderOutput:
    """Splits the composited [C, H, W, 3 + 3 + 3] image (colour, normals, alpha / w z / median)."""
    alpha = img[..., 6:7]
    depth_expected = torch.where(alpha > 0, img[..., 7:8] / torch.where(alpha > 0, alpha, 1.0), 0.0)
    color = img[..., :3]
    if backgrounds is not None:
        color = color + (1.0 - alpha) * backgrounds[:, None, None, :]
    if delta is not None:
        meta.update(gradient_2dgs=delta, width=width, height=height, n_cameras=img.shape[0], gaussian_ids=None)
    return RenderOutput(rgb=color, features=None, alpha=alpha, depth_expected=depth_expected,
                        depth_median=img[..., 8:9], normals=img[..., 3:6], depth_point="intersection", meta=meta)
