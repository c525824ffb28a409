"""Render the 32 canonical lattice views of any 2DGS asset in one call.

The paper's reference views "are deterministically rasterized on a fibonacci hemisphere
lattice from the reconstructed Gaussian asset": view k of every scene is the camera k of
``gspi.data.lattice.lattice_cameras`` (the same cameras as a generated scene's ``train``
split). This lives next to the reconstruction because it is the same renderer applied to
the same cameras, and it depends only on ``gspi.gaussians`` and ``gspi.data.lattice``.
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from gspi.data.lattice import lattice_cameras
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import RenderOutput, render_gaussians

# conf/gspi_data.yaml `lattice:` (the canonical lattice; only the image size varies)
DEFAULT_LATTICE = {"num_views": 32, "radius": 3.0, "fov_deg": 45.0, "min_elevation_deg": 0.0}


def lattice_camera_tensors(image_size: int | tuple[int, int], *, lattice: Optional[dict] = None,
                           dtype=torch.float32, device=None) -> tuple[Tensor, Tensor]:
    """(viewmats [V, 4, 4], Ks [V, 3, 3]) of the canonical lattice at ``image_size``.

    Args:
        image_size: S (square) or (height, width).
        lattice: overrides of :data:`DEFAULT_LATTICE` (keys of ``lattice_cameras``).
    """
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    params = {**DEFAULT_LATTICE, **(lattice or {})}
    K, w2c = lattice_cameras(width=w, height=h, **params)
    return (torch.as_tensor(w2c, dtype=dtype, device=device), torch.as_tensor(K, dtype=dtype, device=device))


def render_lattice_views(gaussians: Gaussians2D, *, image_size: int | tuple[int, int],
                         lattice: Optional[dict] = None, background: Optional[Tensor] = None,
                         with_pbr: bool = False, backend: str = "auto", batch: int = 8,
                         **kwargs) -> RenderOutput:
    """Renders ``gaussians`` into every canonical lattice camera (lattice order).

    Args:
        gaussians: any 2DGS asset (e.g. ``read_ply(".../point_cloud.ply")``).
        image_size: S or (H, W).
        lattice: overrides of :data:`DEFAULT_LATTICE`.
        background: [3] colour composited behind ``rgb`` (default black, the layout's).
        with_pbr: also composite the PBR channels into ``features``.
        backend: rasterizer backend ("auto": gsplat on CUDA, else the torch renderer).
        batch: views per rasterizer call (bounds memory).
        **kwargs: forwarded to ``rasterize_2dgs`` (e.g. ``depth_point``).

    Returns:
        :class:`RenderOutput` with C = 32 views; ``meta["viewmats"]`` and ``meta["Ks"]`` hold
        the cameras (``meta["radii"]`` etc. concatenated over views).
    """
    viewmats, Ks = lattice_camera_tensors(image_size, lattice=lattice, dtype=gaussians.means.dtype,
                                          device=gaussians.device)
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    bg = torch.zeros(3, dtype=gaussians.means.dtype, device=gaussians.device) if background is None else background
    parts = []
    for start in range(0, len(viewmats), batch):
        vm, k = viewmats[start:start + batch], Ks[start:start + batch]
        parts.append(render_gaussians(gaussians, vm, k, w, h, with_pbr=with_pbr, backend=backend,
                                      backgrounds=bg.to(vm)[None].expand(len(vm), -1), **kwargs))
    cat = lambda name: None if getattr(parts[0], name) is None else torch.cat([getattr(p, name) for p in parts])  # noqa: E731
    meta = {key: torch.cat([p.meta[key] for p in parts]) for key in parts[0].meta
            if isinstance(parts[0].meta[key], Tensor)}
    meta.update(viewmats=viewmats, Ks=Ks)
    return RenderOutput(rgb=cat("rgb"), features=cat("features"), alpha=cat("alpha"),
                        depth_expected=cat("depth_expected"), depth_median=cat("depth_median"),
                        normals=cat("normals"), depth_point=parts[0].depth_point, meta=meta)
