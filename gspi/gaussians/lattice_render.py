"""Render the canonical lattice views of any 2DGS asset in one call, and the record they travel in.

The paper's reference views "are deterministically rasterized on a fibonacci hemisphere
lattice from the reconstructed Gaussian asset": view k of every scene is the camera k of
``gspi.data.lattice.lattice_cameras`` (the same cameras as a generated scene's ``train``
split). Stage 0 (its lattice renders), Stage I (the renders it unprojects) and Stage III (the
cameras of its targets) all use this module; it depends only on ``gspi.gaussians`` and
``gspi.data.lattice``.

:class:`LatticeRenders` is what Stage I hands to Stages II and III: the maps *with the cameras
that made them*, so no later stage rebuilds a camera from a default.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from gspi.data.lattice import CANONICAL_LATTICE, lattice_cameras
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import RenderOutput, render_gaussians


@dataclass
class LatticeRenders:
    """Lattice renders as numpy arrays (float32 maps) with their float64 cameras.

    Attributes:
        rgb: [V, H, W, 3] linear radiance.
        alpha: [V, H, W] rendered opacity.
        depth: [V, H, W] median depth (camera z), 0 where nothing is composited.
        K: [V, 3, 3] pixel intrinsics (pixel centres at +0.5).
        w2c: [V, 4, 4] OpenCV world -> camera.
    """

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    w2c: np.ndarray

    def __post_init__(self) -> None:
        v, h, w = self.alpha.shape
        for name, shape in (("rgb", (v, h, w, 3)), ("depth", (v, h, w)), ("K", (v, 3, 3)),
                            ("w2c", (v, 4, 4))):
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"LatticeRenders.{name} must have shape {shape}, got "
                                 f"{tuple(getattr(self, name).shape)}")

    @property
    def num_views(self) -> int:
        return self.alpha.shape[0]

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width)."""
        return self.alpha.shape[1], self.alpha.shape[2]

    FIELDS = ("rgb", "alpha", "depth", "K", "w2c")

    def save(self, path: str | Path) -> Path:
        """Writes ``path`` (.npz, compressed): the five arrays."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **{name: getattr(self, name) for name in self.FIELDS})
        return path

    @classmethod
    def load(cls, path: str | Path) -> "LatticeRenders":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: lattice renders file not found")
        with np.load(path) as data:
            missing = [name for name in cls.FIELDS if name not in data]
            if missing:
                raise ValueError(f"{path}: not lattice renders (missing {missing})")
            return cls(**{name: data[name] for name in cls.FIELDS})


def lattice_camera_tensors(image_size: int | tuple[int, int], *, lattice: Optional[dict] = None,
                           dtype=torch.float32, device=None) -> tuple[Tensor, Tensor]:
    """(viewmats [V, 4, 4], Ks [V, 3, 3]) of the lattice at ``image_size``.

    Args:
        image_size: S (square) or (height, width).
        lattice: overrides of ``gspi.data.lattice.CANONICAL_LATTICE`` (keys of ``lattice_cameras``).
    """
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    K, w2c = lattice_cameras(width=w, height=h, **{**CANONICAL_LATTICE, **(lattice or {})})
    return (torch.as_tensor(w2c, dtype=dtype, device=device), torch.as_tensor(K, dtype=dtype, device=device))


def render_lattice_views(gaussians: Gaussians2D, *, image_size: int | tuple[int, int],
                         lattice: Optional[dict] = None, background: Optional[Tensor] = None,
                         with_pbr: bool = False, backend: str = "auto", batch: int = 8,
                         **kwargs) -> RenderOutput:
    """Renders ``gaussians`` into every lattice camera (lattice order).

    Args:
        gaussians: any 2DGS asset (e.g. ``read_ply(".../point_cloud.ply")``).
        image_size: S or (H, W).
        lattice: overrides of ``CANONICAL_LATTICE``.
        background: [3] colour composited behind ``rgb`` (default black, the layout's).
        with_pbr: also composite the PBR channels into ``features``.
        backend: rasterizer backend ("auto": gsplat on CUDA, numba on CPU, else the torch renderer).
        batch: views per rasterizer call (bounds memory).
        **kwargs: forwarded to ``rasterize_2dgs`` (e.g. ``depth_point``).

    Returns:
        :class:`RenderOutput` with C = V views; ``meta["viewmats"]`` and ``meta["Ks"]`` hold
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


def render_lattice(gaussians: Gaussians2D, *, image_size: int | tuple[int, int],
                   lattice: Optional[dict] = None) -> LatticeRenders:
    """RGB, alpha and median depth of the lattice views (no gradients) with their cameras."""
    with torch.no_grad():
        out = render_lattice_views(gaussians, image_size=image_size, lattice=lattice)
    w2c, K = lattice_camera_tensors(image_size, lattice=lattice, dtype=torch.float64)
    as_np = lambda t: t.detach().float().cpu().numpy()  # noqa: E731
    return LatticeRenders(rgb=as_np(out.rgb), alpha=as_np(out.alpha[..., 0]),
                          depth=as_np(out.depth_median[..., 0]), K=K.numpy(), w2c=w2c.numpy())
