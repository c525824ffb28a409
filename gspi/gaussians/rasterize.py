"""Differentiable rasterization of 2D Gaussian surfels (2DGS), CPU and GPU.

One entry point, :func:`rasterize_2dgs`, modelled on gsplat 1.5.3's
``rasterization_2dgs`` (same argument names and conventions) and returning a
:class:`RenderOutput` with colour, extra features, alpha, expected and median
depth and world-space normals. Backends:

* ``"torch"``: tile-based pure-torch renderer (``torch_backend.py``), any device;
  the reference;
* ``"numba"``: the same tiling with the compositing compiled by numba
  (``numba_composite.py``), CPU tensors only; equal outputs and gradients;
* ``"gsplat"``: gsplat's CUDA kernels (``gsplat_backend.py``), CUDA tensors only;
* ``"auto"``: gsplat for CUDA tensors when it imports, numba for CPU tensors when
  it imports, else torch.

Depth convention (``depth_point``): ``"intersection"`` (default) is the official
hbb1 2DGS rule (``diff-surfel-rasterization`` forward.cu): per pixel, the camera z
of the ray-splat intersection point where the surfel kernel wins the low-pass
min (``u^2 + v^2 <= 2 |p - means2d|^2``), and the centre z where the screen-space
filter wins (sub-pixel or grazing surfels, whose ray-plane hit can lie far away).
``"center"`` is the camera z of the surfel centre everywhere, gsplat's depth
channel. They differ by the surfel's tilt times its extent; both equal z0 for a
fronto-parallel surfel. (hbb1 also skips a surfel at pixels where that depth is
below its near plane; neither gsplat nor this module does.)
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Literal, Optional

import torch
from torch import Tensor

from gspi.gaussians.projection import project_surfels
from gspi.gaussians.render_output import RenderOutput, unit_normals  # noqa: F401 (this module's result type)
from gspi.gaussians.sh import sh_colors
from gspi.gaussians.torch_backend import rasterize_view

if TYPE_CHECKING:
    from gspi.gaussians.model import Gaussians2D

BACKENDS = ("auto", "torch", "numba", "gsplat")
DEPTH_POINTS = ("intersection", "center")


def gsplat_available() -> bool:
    """True when gsplat imports (its CUDA kernels compile on first use)."""
    try:
        import gsplat  # noqa: F401
    except (ImportError, OSError):  # OSError: CUDA runtime libraries missing
        return False
    return True


@functools.cache
def numba_available() -> bool:
    """True when numba (and so the compiled CPU compositor) imports."""
    try:
        import gspi.gaussians.numba_composite  # noqa: F401
    except ImportError:
        return False
    return True


def _resolve_backend(backend: str, device: torch.device) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        if device.type == "cuda" and gsplat_available():
            return "gsplat"
        return "numba" if device.type == "cpu" and numba_available() else "torch"
    if backend == "gsplat" and device.type != "cuda":
        raise ValueError("backend 'gsplat' needs CUDA tensors; use 'numba' or 'torch' on CPU")
    if backend == "numba" and device.type != "cpu":
        raise ValueError(f"backend 'numba' needs CPU tensors, got {device.type}; use 'gsplat' or 'torch'")
    if backend == "numba" and not numba_available():
        raise ValueError("backend 'numba' needs the numba package (pip install numba)")
    return backend


def tile_backend(backend: str, device: torch.device) -> str:
    """The tile renderer's compositor ("torch" or "numba") for callers without a gsplat
    path (``recon.render``): "auto" is numba on CPU when it imports, else torch."""
    if backend == "gsplat":
        raise ValueError("this renderer has no gsplat path; use 'auto', 'numba' or 'torch'")
    resolved = _resolve_backend(backend, device)
    return "torch" if resolved == "gsplat" else resolved


def view_colors(
    colors: Optional[Tensor], means: Tensor, viewmats: Tensor, sh_degree: Optional[int]
) -> Optional[Tensor]:
    """Per-view post-activation colours [C, N, D] from colours or SH coefficients.

    Args:
        colors: [N, D] or [C, N, D] colours, or [N, K, 3] / [C, N, K, 3] SH when
            ``sh_degree`` is set; None passes through.
        means: [N, 3] world-space centres (SH view directions).
        viewmats: [C, 4, 4] world-to-camera.
        sh_degree: SH degree to evaluate, or None for plain colours.
    """
    if colors is None:
        return None
    n_cams, n = viewmats.shape[0], means.shape[0]
    if sh_degree is None:
        if colors.dim() == 2:
            return colors[None].expand(n_cams, -1, -1)
        if colors.dim() == 3 and colors.shape[:2] == (n_cams, n):
            return colors
        raise ValueError(f"colors must be [N, D] or [C, N, D] without sh_degree, got {tuple(colors.shape)}")
    colors = _sh_per_view(colors, n_cams, n)
    centers = torch.linalg.inv(viewmats)[:, :3, 3]
    return torch.stack([sh_colors(sh_degree, colors[c], means, centers[c]) for c in range(n_cams)])


def _sh_per_view(sh: Tensor, n_cams: int, n: int) -> Tensor:
    """SH coefficients [C, N, K, 3] (a view of [N, K, 3] shared by the cameras)."""
    if sh.dim() == 3:
        sh = sh[None].expand(n_cams, -1, -1, -1)
    if sh.dim() != 4 or sh.shape[-1] != 3 or sh.shape[:2] != (n_cams, n):
        raise ValueError(f"SH colors must be [N, K, 3] or [C, N, K, 3], got {tuple(sh.shape)}")
    return sh


def _check_inputs(means, quats, scales, opacities, viewmats, Ks, features, backgrounds, depth_point) -> None:
    n = means.shape[0]
    if means.shape != (n, 3) or quats.shape != (n, 4) or opacities.shape != (n,):
        raise ValueError(
            f"expected means [N, 3], quats [N, 4], opacities [N]; got {tuple(means.shape)}, "
            f"{tuple(quats.shape)}, {tuple(opacities.shape)}"
        )
    if scales.dim() != 2 or scales.shape[0] != n or scales.shape[1] not in (2, 3):
        raise ValueError(f"scales must be [N, 2] (or [N, 3], third ignored), got {tuple(scales.shape)}")
    if viewmats.dim() != 3 or viewmats.shape[1:] != (4, 4) or Ks.shape != (viewmats.shape[0], 3, 3):
        raise ValueError(
            f"expected viewmats [C, 4, 4] and Ks [C, 3, 3], got {tuple(viewmats.shape)}, {tuple(Ks.shape)}"
        )
    if features is not None and (features.dim() not in (2, 3) or features.shape[-2] != n):
        raise ValueError(f"features must be [N, D] or [C, N, D], got {tuple(features.shape)}")
    if backgrounds is not None and backgrounds.dim() != 2:
        raise ValueError(f"backgrounds must be [C, D], got {tuple(backgrounds.shape)}")
    if depth_point not in DEPTH_POINTS:
        raise ValueError(f"depth_point must be one of {DEPTH_POINTS}, got {depth_point!r}")


def rasterize_2dgs(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 2]
    opacities: Tensor,  # [N]
    colors: Optional[Tensor],  # [N, D], [C, N, D] or SH [N, K, 3]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    features: Optional[Tensor] = None,  # [N, D] or [C, N, D]
    sh_degree: Optional[int] = None,
    backgrounds: Optional[Tensor] = None,  # [C, D]
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    depth_point: Literal["intersection", "center"] = "intersection",
    backend: Literal["auto", "torch", "numba", "gsplat"] = "auto",
    tile_size: int = 8,
    max_elems: int = 1 << 20,
) -> RenderOutput:
    """Renders 2D Gaussian surfels into C pinhole cameras (2DGS / gsplat semantics).

    All inputs are ACTIVATED values (exp-ed scales, sigmoid-ed opacities); quats are
    normalised internally. Differentiable w.r.t. means, quats, scales, opacities,
    colors / SH and features with both backends.

    Args:
        means: world-space centres, [N, 3].
        quats: (w, x, y, z) rotations, [N, 4].
        scales: tangent-axis scales in world units, [N, 2] ([N, 3] accepted, third ignored).
        opacities: opacities in [0, 1], [N].
        colors: post-activation colours [N, D] / [C, N, D], or SH coefficients
            [N, K, 3] / [C, N, K, 3] when ``sh_degree`` is set (rgb = max(SH + 0.5, 0),
            per-view directions centre - camera). None renders no colour.
        viewmats: world-to-camera matrices, [C, 4, 4], OpenCV axes (x right, y down, z fwd).
        Ks: pixel intrinsics, [C, 3, 3]; pixel (j, i) has centre (j + 0.5, i + 0.5).
        width: image width in pixels.
        height: image height in pixels.
        features: extra per-surfel channels composited like colours (e.g. 5 PBR values),
            [N, D] or [C, N, D]; over a zero background.
        sh_degree: SH degree to evaluate (0..3) if ``colors`` holds SH, else None.
        backgrounds: [C, D] background colour added as ``(1 - alpha) * bg`` to ``rgb``.
        near_plane: surfels with centre depth <= near_plane are culled.
        far_plane: surfels with centre depth >= far_plane are culled.
        depth_point: "intersection" (hbb1 2DGS rule; default) or "center" (gsplat's depth).
            With backend "gsplat" the expected depth is always centre-based (gsplat has no
            per-pixel intersection depth); the median depth honours ``depth_point``.
        backend: "auto", "torch", "numba" or "gsplat" (see module docstring).
        tile_size: tile side of the torch / numba backends in pixels. 8 measured fastest overall on
            CPU (4 wins for sub-pixel surfels, 16 loses on both small and large ones).
        max_elems: surfel-pixel pairs per batched op in the torch backend.

    Returns:
        :class:`RenderOutput`.

    Raises:
        ValueError: on wrong shapes or unknown option values.
    """
    _check_inputs(means, quats, scales, opacities, viewmats, Ks, features, backgrounds, depth_point)
    backend = _resolve_backend(backend, means.device)
    feats_in = features
    if features is not None and features.dim() == 2:
        feats_in = features[None].expand(len(viewmats), -1, -1)
    if backend == "numba" and not (viewmats.requires_grad or Ks.requires_grad):
        out = _rasterize_numba(
            means, quats, scales, opacities, colors, sh_degree, feats_in, viewmats, Ks, width, height,
            near_plane=near_plane, far_plane=far_plane, depth_point=depth_point, tile_size=tile_size,
        )
        if backgrounds is not None and out.rgb is not None:
            out.rgb = out.rgb + (1.0 - out.alpha) * backgrounds[:, None, None, :]
        return out
    rgb_in = view_colors(colors, means, viewmats, sh_degree)
    if backend == "gsplat":
        from gspi.gaussians.gsplat_backend import rasterize_gsplat

        out = rasterize_gsplat(
            means, quats, scales, opacities, rgb_in, feats_in, viewmats, Ks, width, height,
            near_plane=near_plane, far_plane=far_plane, depth_point=depth_point,
        )
    else:
        out = _rasterize_torch(
            means, quats, scales, opacities, rgb_in, feats_in, viewmats, Ks, width, height,
            near_plane=near_plane, far_plane=far_plane, depth_point=depth_point,
            tile_size=tile_size, max_elems=max_elems, composite=backend,
        )
    if backgrounds is not None and out.rgb is not None:
        out.rgb = out.rgb + (1.0 - out.alpha) * backgrounds[:, None, None, :]
    return out


def _rasterize_torch(
    means, quats, scales, opacities, rgb, feats, viewmats, Ks, width, height, *,
    near_plane, far_plane, depth_point, tile_size, max_elems, composite,
) -> RenderOutput:
    """Tile backends (torch / numba compositing): projects once, rasterizes the views one
    after another."""
    proj = project_surfels(means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane)
    d_rgb = 0 if rgb is None else rgb.shape[-1]
    d_feat = 0 if feats is None else feats.shape[-1]
    images = []
    for c in range(len(viewmats)):
        chans = [t[c] for t in (rgb, feats) if t is not None] + [proj.normals[c]]
        in_range = (proj.depths[c] > near_plane) & (proj.depths[c] < far_plane)
        images.append(
            rasterize_view(
                proj.ray_transforms[c], proj.means2d[c], proj.depths[c], opacities, torch.cat(chans, -1),
                in_range, width, height, tile_size=tile_size,
                intersection_depth=depth_point == "intersection", max_elems=max_elems, composite=composite,
            )
        )
    meta = {"radii": proj.radii, "means2d": proj.means2d, "depths": proj.depths}
    return _render_output(torch.stack(images), d_rgb if rgb is not None else None,
                          d_feat if feats is not None else None, depth_point, meta)


def _rasterize_numba(
    means, quats, scales, opacities, colors, sh_degree, feats, viewmats, Ks, width, height, *,
    near_plane, far_plane, depth_point, tile_size,
) -> RenderOutput:
    """The numba backend: per view, the compiled projection + SH colour
    (``numba_projection.project_view``) and the compiled compositing; equal to the torch
    path's outputs and gradients (camera gradients excepted: see the caller)."""
    from gspi.gaussians.numba_projection import project_view
    from gspi.gaussians.torch_backend import padded_table, rasterize_table

    n_cams, n = len(viewmats), means.shape[0]
    sh = None
    plain = view_colors(colors, means, viewmats, None) if colors is not None and sh_degree is None else None
    if colors is not None and sh_degree is not None:
        sh = _sh_per_view(colors, n_cams, n)
    images, views = [], []
    for c in range(n_cams):
        # shared [N, K, 3] coefficients go in as they are: selecting from their expanded [C, ...]
        # view costs a zero-filled [1, N, K, 3] buffer and a copy per view in the backward
        sh_view = None if sh is None else (colors if colors.dim() == 3 else sh[c])
        view = project_view(means, quats, scales, opacities, viewmats[c], Ks[c], width, height,
                            sh=sh_view, sh_degree=sh_degree if sh is not None else None,
                            near_plane=near_plane, far_plane=far_plane)
        chans = [t for t in (view.rgb, None if plain is None else plain[c], None if feats is None else feats[c])
                 if t is not None] + [view.normals]
        table = padded_table(torch.cat([view.geometry] + chans, -1))
        images.append(rasterize_table(table, view.ray_transforms, opacities, view.in_range, width, height,
                                      tile_size=tile_size, intersection_depth=depth_point == "intersection",
                                      composite="numba"))
        views.append(view)
    d_rgb = None if colors is None else (3 if sh is not None else plain.shape[-1])
    meta = {"radii": torch.stack([v.radii for v in views]), "means2d": torch.stack([v.means2d for v in views]),
            "depths": torch.stack([v.depths for v in views])}
    return _render_output(torch.stack(images), d_rgb, None if feats is None else feats.shape[-1], depth_point, meta)


def _render_output(img: Tensor, d_rgb: Optional[int], d_feat: Optional[int], depth_point: str,
                   meta: dict) -> RenderOutput:
    """Splits the composited [C, H, W, rgb + features + normals + (alpha, w z, median)] image."""
    # one split, not six slices: its backward is one cat, where each slice's backward
    # zero-fills a full-size image (6 fills of [C, H, W, F + 3] per step)
    rgb, features, normals, alpha, w_z, depth_median = img.split([d_rgb or 0, d_feat or 0, 3, 1, 1, 1], -1)
    depth_expected = torch.where(alpha > 0, w_z / torch.where(alpha > 0, alpha, 1.0), 0.0)
    return RenderOutput(
        rgb=rgb if d_rgb is not None else None,
        features=features if d_feat is not None else None,
        alpha=alpha,
        depth_expected=depth_expected,
        depth_median=depth_median,
        normals=normals,
        depth_point=depth_point,
        meta=meta,
    )


def render_gaussians(
    gaussians: "Gaussians2D",
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    *,
    with_pbr: bool = False,
    **kwargs,
) -> RenderOutput:
    """Convenience wrapper: renders a :class:`Gaussians2D` (SH colour, optional PBR).

    Args:
        gaussians: the surfels (raw parameters; activated here).
        viewmats: [C, 4, 4] world-to-camera.
        Ks: [C, 3, 3] intrinsics.
        width: image width.
        height: image height.
        with_pbr: also composite the 5 PBR channels (albedo RGB, roughness, metallic)
            into ``features``; needs ``gaussians.has_pbr``.
        **kwargs: forwarded to :func:`rasterize_2dgs` (backgrounds, backend, ...).
    """
    features = gaussians.pbr_features() if with_pbr else kwargs.pop("features", None)
    return rasterize_2dgs(
        gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities, gaussians.sh,
        viewmats, Ks, width, height, features=features, sh_degree=gaussians.sh_degree, **kwargs,
    )
