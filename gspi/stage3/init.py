"""Prior-guided initialisation of the per-Gaussian PBR logits (paper, Stage III, first paragraph).

For every Gaussian centre mu_i and every lattice view v:

1. project: ``(u, v) = K (R mu_i + t)`` in continuous pixel coordinates (pixel (row r, col c)
   spans [c, c + 1) x [r, r + 1), centre at +0.5), camera depth ``z``;
2. visibility: the centre must lie in the image, in front of the camera, and within
   ``depth_tolerance_px * z / fx`` (that many pixel footprints) of the input asset's rendered
   MEDIAN depth at the pixel containing it (2DGS's surface depth), so surfels hidden behind
   the visible surface do not take its colour;
3. gather bilinearly among VALID target pixels: the four neighbours' weights are multiplied by
   their validity and renormalised (a sample needs a positive valid weight). Albedo is gathered
   in linear RGB (``srgb_to_linear`` of the sRGB target), roughness and metallic as they are.

The attribute is the plain mean of the Gaussian's samples over views. Gaussians with no
sample take the value of the nearest initialised Gaussian (``fallback: nearest``, by centre
distance) or the mean of all valid target pixels (``fallback: mean``, also used when no
Gaussian got a sample).

SH-DC harmonisation of the albedo (strength beta = ``sh_harmonize``, mode ``sh_gain``): the
base colour of the SH degree-0 term, ``c_i = clamp(0.5 + C0 f_dc, 0, 1)`` (linear radiance), is
mapped onto the albedo scale and blended in, ``a_i <- (1 - beta) a_i + beta S_i``, all linear:

* ``channel``: ``S_i = clamp(g c_i, 0, 1)`` with one least-squares gain per channel fitted over the
  initialised Gaussians, ``g_k = sum_i a_ik c_ik / sum_i c_ik^2`` (the mean irradiance the
  reconstruction baked into its colours);
* ``scalar``: the same with one gain for the three channels (keeps the SH hue);
* ``chroma`` (the default, chosen on the validation scenes, docs/STAGE3.md): ``S_i = mean_k(a_i)
  c_i / mean_k(c_i)``, the gathered albedo's own level with the reconstruction's chromaticity.
  Under near-white capture light the SH colour's hue is the albedo's, while its level carries
  the baked shading; Stage II removes the shading but the small model loses the hue.

Constant targets over a constant-colour asset stay exactly constant in the gain modes (g c_i =
a_i); with ``stage3.init.harmonize_targets`` the staged albedo targets get the same blend per
pixel (``gspi.stage3.distill.harmonized_albedo_targets``), so distillation keeps it.

Logits are ``logit(clamp(value, eps, 1 - eps))``.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial import cKDTree
from torch import Tensor

from eval.common.colorspace import srgb_to_linear
from gspi.gaussians.model import Gaussians2D
from gspi.stage3.config import SH_MODES, Stage3Config
from gspi.stage3.render import render_geometry
from gspi.stage3.targets import StagedTargets

NEAR_PLANE = 0.01


def project_points(xyz: Tensor, K: Tensor, w2c: Tensor) -> tuple[Tensor, Tensor]:
    """Continuous pixel coordinates and camera depth of world points.

    Args:
        xyz: [N, 3] world points.
        K: [V, 3, 3] intrinsics; w2c: [V, 4, 4] world-to-camera.

    Returns:
        (uv [V, N, 2] as (x = column, y = row) with pixel centres at +0.5, z [V, N] camera depth).
    """
    cam = torch.einsum("vij,nj->vni", w2c[:, :3, :3], xyz) + w2c[:, None, :3, 3]
    z = cam[..., 2]
    pix = torch.einsum("vij,vnj->vni", K, cam)
    uv = pix[..., :2] / torch.where(z.abs() > 1e-12, z, torch.full_like(z, 1e-12))[..., None]
    return uv, z


def gather_valid_bilinear(maps: Tensor, valid: Tensor, uv: Tensor) -> tuple[Tensor, Tensor]:
    """Bilinear samples of ``maps`` that use only valid pixels (weights renormalised).

    Args:
        maps: [V, H, W, C] per-view maps.
        valid: [V, H, W] bool.
        uv: [V, N, 2] continuous pixel coordinates (x, y), pixel centres at +0.5.

    Returns:
        (values [V, N, C], weight [V, N] total valid bilinear weight in [0, 1]; 0 = no sample).
    """
    v, h, w, c = maps.shape
    stack = torch.cat([maps * valid[..., None], valid[..., None].to(maps)], -1).permute(0, 3, 1, 2)
    grid = torch.stack([2 * uv[..., 0] / w - 1, 2 * uv[..., 1] / h - 1], -1)[:, None]  # [V, 1, N, 2]
    sampled = F.grid_sample(stack, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    sampled = sampled[:, :, 0].permute(0, 2, 1)  # [V, N, C + 1]
    weight = sampled[..., -1]
    values = sampled[..., :-1] / weight.clamp_min(1e-12)[..., None]
    return values, weight


def visible_in_views(uv: Tensor, z: Tensor, depth: Tensor, K: Tensor, tolerance_px: float) -> Tensor:
    """[V, N] bool: the point lies in the image, in front, and on the rendered median-depth surface.

    Args:
        uv: [V, N, 2] pixel coordinates; z: [V, N] camera depth.
        depth: [V, H, W] rendered median depth (0 = empty pixel).
        K: [V, 3, 3] intrinsics (fx sets the pixel footprint ``z / fx``).
        tolerance_px: allowed |z - depth| in pixel footprints.
    """
    v, h, w = depth.shape
    col, row = torch.floor(uv[..., 0]).long(), torch.floor(uv[..., 1]).long()
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h) & (z > NEAR_PLANE)
    flat = (torch.arange(v, device=depth.device)[:, None] * h + row.clamp(0, h - 1)) * w + col.clamp(0, w - 1)
    surface = depth.reshape(-1)[flat]
    tolerance = tolerance_px * z / K[:, 0, 0, None]
    return inside & (surface > 0) & ((z - surface).abs() <= tolerance)


def _logit(x: Tensor, eps: float) -> Tensor:
    return torch.logit(x.clamp(eps, 1.0 - eps))


def _fallback(values: Tensor, has: Tensor, means: Tensor, kind: str, target_mean: Tensor) -> Tensor:
    """Fills rows of ``values`` [N, C] without samples (``~has``)."""
    missing = ~has
    if not missing.any():
        return values
    out = values.clone()
    if kind == "nearest" and has.any():
        tree = cKDTree(means[has].detach().cpu().double().numpy())
        _, idx = tree.query(means[missing].detach().cpu().double().numpy())
        out[missing] = values[has][torch.as_tensor(np.atleast_1d(idx), device=values.device)]
    else:
        out[missing] = target_mean
    return out


def sh_gain(albedo_linear: Tensor, base_color: Tensor, has: Tensor, kind: str = "channel") -> Tensor:
    """[3] least-squares gain mapping the SH colours onto the gathered albedo (module docstring).

    ``kind="channel"`` fits one gain per channel, ``g_k = sum_i a_ik c_ik / sum_i c_ik^2``;
    ``"scalar"`` one gain for all three, ``g = sum_ik a_ik c_ik / sum_ik c_ik^2`` (repeated x3), so
    ``g c_i`` keeps the reconstruction's hue and takes only the albedo's level. ``"chroma"`` needs
    no gain (ones).
    """
    if kind == "chroma":
        return torch.ones(3, dtype=albedo_linear.dtype, device=albedo_linear.device)
    c = base_color.clamp(0.0, 1.0)
    fit = has if has.any() else torch.ones_like(has)
    num, den = (albedo_linear[fit] * c[fit]).sum(0), (c[fit] ** 2).sum(0)
    if kind == "scalar":
        num, den = num.sum().expand(3), den.sum().expand(3)
    elif kind != "channel":
        raise ValueError(f"sh_gain kind must be one of {SH_MODES}, got {kind!r}")
    return torch.where(den > 0, num / den.clamp_min(1e-12), torch.zeros_like(num))


def sh_colour_on_albedo_scale(albedo_linear: Tensor, base_color: Tensor, gain: Tensor, kind: str) -> Tensor:
    """The SH colour mapped onto the albedo: ``clamp(g c)`` (gain kinds) or, for ``"chroma"``, the
    albedo's own level with the SH colour's chromaticity ``mean_k(a) c / mean_k(c)`` (the albedo
    where ``mean_k(c)`` < 1e-4)."""
    c = base_color.clamp(0.0, 1.0)
    if kind != "chroma":
        return (gain * c).clamp(0.0, 1.0)
    level_c = c.mean(-1, keepdim=True)
    dark = level_c < 1e-4
    moved = albedo_linear.mean(-1, keepdim=True) * c / torch.where(dark, torch.ones_like(level_c), level_c)
    return torch.where(dark, albedo_linear, moved).clamp(0.0, 1.0)


def blend_base_color(albedo_linear: Tensor, base_color: Tensor, gain: Tensor, beta: float,
                     kind: str = "channel") -> Tensor:
    """``(1 - beta) a + beta S(a, c)``, S = :func:`sh_colour_on_albedo_scale` (linear RGB, any
    leading shape, channels last)."""
    if beta == 0.0:
        return albedo_linear
    return (1.0 - beta) * albedo_linear + beta * sh_colour_on_albedo_scale(albedo_linear, base_color, gain, kind)


def harmonize_albedo(albedo_linear: Tensor, base_color: Tensor, has: Tensor, beta: float,
                     kind: str = "channel") -> tuple[Tensor, Tensor]:
    """SH-DC harmonisation (module docstring): returns (albedo [N, 3] linear, gain [3])."""
    gain = sh_gain(albedo_linear, base_color, has, kind)
    return blend_base_color(albedo_linear, base_color, gain, beta, kind), gain


def initialize_pbr(asset: Gaussians2D, targets: StagedTargets, cfg: Stage3Config, *,
                   depth: Optional[Tensor] = None) -> tuple[Gaussians2D, dict]:
    """Initial albedo / roughness / metallic logits by multi-view back-projection.

    Args:
        asset: the input 2DGS asset (its PBR logits, if any, are replaced).
        targets: staged per-view targets with their cameras.
        cfg: Stage III config (``cfg.init``, ``cfg.backend``).
        depth: optional [V, H, W] median depth of ``asset`` in the target views (rendered here
            when None).

    Returns:
        (copy of ``asset`` with PBR logits, stats: num_gaussians, initialised (>= 1 valid
        sample), fallback (count), fallback_kind, mean_samples, occluded_samples (in-image
        samples on valid pixels rejected by the depth test), sh_gain [3], sh_harmonize).

    Raises:
        ValueError: if no target pixel is valid.
    """
    t = targets.tensors(asset.device)
    if not t["valid"].any():
        raise ValueError("staged targets have no valid pixel: nothing to initialise from")
    means = asset.means.detach()
    K, w2c = t["K"].to(means), t["w2c"].to(means)
    if depth is None:
        _, depth = render_geometry(asset.detach(), w2c, K, targets.width, targets.height, backend=cfg.backend)
    maps = torch.cat([srgb_to_linear(t["albedo"]), t["roughness"], t["metallic"]], -1).to(means)
    uv, z = project_points(means, K, w2c)
    values, weight = gather_valid_bilinear(maps, t["valid"], uv)
    on_target = weight > 1e-6
    visible = visible_in_views(uv, z, depth.to(means), K, cfg.init.depth_tolerance_px)
    use = (on_target & visible).to(means)  # [V, N]
    count = use.sum(0)
    has = count > 0
    mean = (values * use[..., None]).sum(0) / count.clamp_min(1)[:, None]
    target_mean = maps[t["valid"]].mean(0)
    mean = _fallback(mean, has, means, cfg.init.fallback, target_mean)
    albedo, gain = harmonize_albedo(mean[:, :3], asset.base_color().detach(), has, cfg.init.sh_harmonize,
                                   cfg.init.sh_gain)
    eps = cfg.init.logit_eps
    out = asset.detach().clone().with_pbr(_logit(albedo, eps), _logit(mean[:, 3:4], eps), _logit(mean[:, 4:5], eps))
    stats = {
        "num_gaussians": asset.num_gaussians, "initialised": int(has.sum()),
        "fallback": int((~has).sum()),
        "fallback_kind": cfg.init.fallback if has.any() else "mean",
        "mean_samples": float(count.mean()),
        "occluded_samples": int((on_target & ~visible & (z > NEAR_PLANE)).sum()),
        "sh_gain": [float(x) for x in gain], "sh_harmonize": cfg.init.sh_harmonize,
        "sh_gain_kind": cfg.init.sh_gain,
    }
    return out, stats
