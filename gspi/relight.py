"""Relighting a PBR-GS asset: deferred split-sum shading of its own surfels (the product).

The asset is rasterized once per view into G-buffers: the blend-weight average of the
surfels' LINEAR albedo, roughness and metallic (``Gaussians2D.pbr_features``) and their
camera-facing normals (``RenderOutput.normals``, renormalised). Each pixel is then shaded by
the evaluator's split-sum shader (``eval.relight.split_sum``, the one that renders the
benchmark's relit ground truth), so relighting an asset and scoring a method agree on the
lighting model; only the normals differ (the asset's own surfels here, ground truth there).

Environments are lat-long, Z-up (docs/FORMAT.md): an HDR file (EXR) or the name of one of the
benchmark's procedural environments (``gspi.data.environments``). Rotation turns the
environment about +Z; exposure is in stops before the tone map.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from eval.common.colorspace import tonemap
from eval.common.errors import StatedError
from eval.relight import PrefilteredEnvironment, prefilter_environment, split_sum
from eval.views import view_directions
from gspi.gaussians.cameras import intrinsics_from_fov, look_at
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import rasterize_2dgs

MIN_ALPHA = 1e-4  # as gspi.stage3.render: below this a pixel shows no surfel


class EnvironmentSpecError(StatedError, ValueError):
    """``env=`` names neither an environment file nor a known environment."""


class NotPBRAssetError(StatedError, ValueError):
    """The asset has no PBR attributes (a plain 2DGS/3DGS file, not GS-PI's pbr_gs.ply)."""


def load_environment(spec: str | Path, *, height: int = 128) -> Tensor:
    """[H, W, 3] linear HDR lat-long map from an EXR path or a known environment name.

    Raises:
        ValueError: ``spec`` is neither an existing file nor a known name (the message lists
            the names).
    """
    from eval.common.imageio import read_exr
    from gspi.data.environments import env_names, make_environment

    path = Path(spec)
    if path.is_file():
        return torch.from_numpy(np.ascontiguousarray(read_exr(path)))
    known = env_names("capture") + env_names("heldout")
    if str(spec) in known:
        return make_environment(str(spec), height)
    raise EnvironmentSpecError(f"env={spec!r} is neither an environment file nor a known environment; "
                     f"known names: {', '.join(known)}")


def rotate_environment(env: Tensor, degrees: float) -> Tensor:
    """Turn a lat-long map about +Z by ``degrees`` (rounded to whole texels; positive =
    counter-clockwise seen from above: light from azimuth a comes from a + degrees). The
    azimuth decreases with the column (docs/FORMAT.md), so texel c takes texel c + shift."""
    width = env.shape[1]
    shift = int(round(degrees / 360.0 * width)) % width
    return torch.roll(env, shifts=-shift, dims=1)


def orbit_cameras(azimuths_deg, elevations_deg, *, radius: float, target, width: int, height: int,
                  fov_deg: float) -> tuple[Tensor, Tensor]:
    """Cameras on a sphere around ``target`` looking at it, world Z up.

    Returns:
        (w2c [C, 4, 4], K [C, 3, 3]) float32, OpenCV axes.
    """
    az = torch.tensor([math.radians(a) for a in azimuths_deg], dtype=torch.float64)
    el = torch.tensor([math.radians(e) for e in elevations_deg], dtype=torch.float64)
    target = torch.as_tensor(target, dtype=torch.float64)
    dirs = torch.stack([az.cos() * el.cos(), az.sin() * el.cos(), el.sin()], dim=-1)
    w2c = look_at(target + radius * dirs, target.expand_as(dirs),
                  torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(dirs))
    K = intrinsics_from_fov(math.radians(fov_deg), width, height, dtype=torch.float64)
    return w2c.float(), K.expand(len(az), 3, 3).float().clone()


def framing(asset: Gaussians2D, fov_deg: float, margin: float = 1.15) -> tuple[Tensor, float]:
    """(centre [3], camera distance) so the asset's bounding sphere fills the view."""
    means = asset.means.detach().double()
    lo, hi = means.quantile(0.01, dim=0), means.quantile(0.99, dim=0)
    centre = (lo + hi) / 2
    radius = float((means - centre).norm(dim=-1).quantile(0.99).clamp_min(1e-6))
    return centre.float(), margin * radius / math.sin(math.radians(fov_deg) / 2)


@dataclass
class ShadedViews:
    """Linear relit radiance and coverage of C views."""

    radiance: Tensor  # [C, H, W, 3] linear HDR, 0 where alpha <= MIN_ALPHA
    alpha: Tensor     # [C, H, W, 1] accumulated opacity


@torch.no_grad()
def shade_asset(asset: Gaussians2D, env: Tensor | PrefilteredEnvironment, w2c: Tensor, K: Tensor,
                width: int, height: int, *, backend: str = "auto") -> ShadedViews:
    """Deferred split-sum shading of a PBR asset at C cameras.

    Args:
        asset: surfels with PBR logits (``asset.has_pbr``).
        env: [h, w, 3] linear lat-long map or a prefiltered environment.
        w2c: [C, 4, 4] world-to-camera (OpenCV). K: [C, 3, 3] intrinsics.
    Returns:
        ShadedViews (radiance not tone-mapped, not exposed).
    Raises:
        ValueError: the asset has no PBR attributes (a plain 2DGS asset, not GS-PI's output).
    """
    if not asset.has_pbr:
        raise NotPBRAssetError("the asset has no PBR attributes (albedo/roughness/metallic logits): "
                               "relight GS-PI's pbr_gs.ply, not a plain 2DGS asset")
    pre = env if isinstance(env, PrefilteredEnvironment) else prefilter_environment(env.float())
    out = rasterize_2dgs(asset.means, asset.quats, asset.scales, asset.opacities, None,
                         w2c.to(asset.means), K.to(asset.means), width, height,
                         features=asset.pbr_features(), backend=backend)
    covered = out.alpha > MIN_ALPHA
    gbuf = out.features / torch.where(covered, out.alpha, torch.ones_like(out.alpha))
    normal = torch.nn.functional.normalize(out.normals, dim=-1)
    frames = []
    for c in range(len(w2c)):
        view = view_directions(K[c].double().numpy(), w2c[c].double().numpy(), height, width)
        n = torch.where(covered[c], normal[c].float(), view)  # any unit vector where empty
        rgb = split_sum(gbuf[c, ..., :3].float().clamp(0, 1), gbuf[c, ..., 3:4].float(),
                        gbuf[c, ..., 4:5].float(), n, view, pre)
        frames.append(torch.where(covered[c], rgb, torch.zeros_like(rgb)))
    return ShadedViews(radiance=torch.stack(frames), alpha=out.alpha.float())


def to_display(shaded: ShadedViews, *, exposure_stops: float = 0.0, tonemap_mode: str = "aces",
               background=(1.0, 1.0, 1.0)) -> np.ndarray:
    """[C, H, W, 3] uint8 sRGB: exposed, tone-mapped, composited over ``background`` (display
    values) with the asset's alpha."""
    rgb = tonemap(shaded.radiance, mode=tonemap_mode, exposure_stops=exposure_stops)
    a = shaded.alpha.clamp(0, 1)
    rgb = rgb * a + torch.tensor(background, dtype=rgb.dtype) * (1 - a)
    return (rgb.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()
