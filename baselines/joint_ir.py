"""In-house joint inverse rendering (GS-IR / R3DG style): materials and lighting together.

The class of method the paper argues against, run on the same 2DGS asset as GS-PI:

1. read the scene's input views (the ``train`` split: ``rgb.exr`` linear HDR + ``mask.png``);
2. freeze the geometry, extract each view's compositing weights once
   (``joint_ir_weights.py``), render the 2DGS normals;
3. optimise per-Gaussian albedo (linear RGB), roughness and metallic logits and a
   learnable ``h x 2h`` lat-long environment (log radiance) with Adam, shading the
   rasterized maps with the evaluator's split-sum (``joint_ir_shading.py``) and comparing
   with the inputs in display space, plus the usual priors (``joint_ir_losses.py``);
4. render the learned maps at the scene's ``test`` views and write them in the canonical
   layout (albedo sRGB-encoded, 16-bit PNGs).

Device: ``predict_scene(..., device=)`` (gspi-run's ``device=``) moves the asset and the
input views there; weights, shading, the optimisation and the test renders run on it (the
view order is still drawn by a CPU generator: the same order on every device) and the maps
come back to the CPU at the write. On the CPU this is the code path of before.

Why a low-resolution lat-long map rather than SH: the split-sum shader needs prefiltered
levels down to roughness 0.1, which low-order SH cannot represent, and a lat-long map
goes through the evaluator's own prefiltering operators exactly (linear, precomputed).
Why log space: the capture environments are HDR with a sun (radiance spans ~4 decades);
``exp`` keeps the map positive and gives relative-size updates.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Mapping

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from baselines.joint_ir_losses import edge_aware_smoothness, white_light_prior
from baselines.joint_ir_shading import prefilter_learnable, prefilter_operators
from baselines.joint_ir_weights import ViewWeights, compositing_weights
from eval.common.colorspace import linear_to_srgb
from eval.common.layout import Scene, write_material
from eval.relight import split_sum
from eval.views import view_directions
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import render_gaussians
from gspi.recon.data import SceneViews, load_scene_views
from gspi.recon.losses import display, photometric_loss

log = logging.getLogger(__name__)

__all__ = ["JointIRConfig", "predict_scene", "fit_materials"]


@dataclass
class JointIRConfig:
    """Options of ``conf/method/joint_ir.yaml`` (see there for the why of each value)."""

    iterations: int = 500
    views_per_iteration: int = 4
    image_size: int | None = None      # optimisation views' side in px; None = native
    env_height: int = 16               # learnable lat-long map is env_height x 2 env_height
    lr_albedo: float = 0.02
    lr_roughness: float = 0.02
    lr_metallic: float = 0.02
    lr_env: float = 0.05
    init_albedo: float = 0.5
    init_roughness: float = 0.6
    init_metallic: float = 0.05
    lambda_dssim: float = 0.2
    lambda_albedo_smooth: float = 0.05
    lambda_roughness_smooth: float = 0.05
    lambda_metallic_smooth: float = 0.05
    smooth_gamma: float = 10.0
    lambda_metallic: float = 0.01
    lambda_env_white: float = 0.0
    tonemap: str = "aces"
    silhouette_alpha: float = 0.004    # ~1/255: pixels where any surfel is composited
    seed: int = 0
    log_every: int = 100

    @classmethod
    def from_mapping(cls, cfg: Mapping | None) -> "JointIRConfig":
        """Builds the config from ``conf/method/joint_ir.yaml`` (``name``/``_target_`` ignored).

        Raises:
            ValueError: on an unknown key, naming the allowed ones.
        """
        values = {k: v for k, v in dict(cfg or {}).items() if k not in ("name", "_target_")}
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown joint_ir option(s) {unknown}; allowed: {sorted(known)}")
        return cls(**values)


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


def resize_views(views: SceneViews, size: int | None) -> SceneViews:
    """Views at ``size x size`` px (area resampling, intrinsics scaled); as is when None."""
    if size is None or (size == views.height and size == views.width):
        return views
    if views.height != views.width:
        raise ValueError(f"image_size needs square views, got {views.height}x{views.width}")
    s = size / views.width
    images = F.interpolate(views.images.permute(0, 3, 1, 2), size=(size, size), mode="area")
    masks = F.interpolate(views.masks[:, None].float(), size=(size, size), mode="area")[:, 0] > 0.5
    Ks = views.Ks.clone()
    Ks[:, :2] *= s
    return SceneViews(views.ids, images.permute(0, 2, 3, 1).contiguous(), masks, views.viewmats, Ks)


CROP_MARGIN = 6  # px around the foreground: covers the 11 px SSIM window's half width


@dataclass
class _ViewData:
    """Everything one optimisation view needs, frozen.

    Images are cropped to ``crop`` (rows, cols slices shared by all views): the union of
    every view's input mask and rendered footprint plus a margin, so the loss and priors
    skip the empty background (outside it prediction and input are both black).
    """

    weights: ViewWeights
    view_dirs: Tensor      # [P, 3] surface -> camera
    target: Tensor         # [h, w, 3] cropped input in display values
    valid: Tensor          # [h, w] bool: input mask and rendered silhouette
    crop: tuple[slice, slice]

    def cropped(self, values: Tensor) -> Tensor:
        """[P, D] per-pixel values -> [h, w, D] cropped image (0 elsewhere)."""
        return self.weights.to_image(values)[self.crop]


def _union_crop(masks: Tensor, margin: int) -> tuple[slice, slice]:
    """Row and column slices bounding the union of [V, H, W] bool masks, plus a margin."""
    rows = torch.nonzero(masks.any(0).any(1)).flatten()
    cols = torch.nonzero(masks.any(0).any(0)).flatten()
    if len(rows) == 0:
        return slice(None), slice(None)
    h, w = masks.shape[1:]
    return (slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + 1 + margin, h)),
            slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + 1 + margin, w)))


def _prepare_views(asset: Gaussians2D, views: SceneViews, cfg: JointIRConfig) -> list[_ViewData]:
    """Every view's frozen weights, directions, display-space target and crop (views' device);
    views with no valid pixel are left out."""
    weights = [compositing_weights(asset, views.viewmats[i], views.Ks[i], views.width, views.height)
               for i in range(views.num_views)]
    footprints = torch.stack([w.to_image(torch.ones_like(w.alpha)[:, None])[..., 0] > 0
                              for w in weights])
    crop = _union_crop(footprints | views.masks, CROP_MARGIN)
    out = []
    for i, w in enumerate(weights):
        dirs = view_directions(views.Ks[i].cpu().numpy(), views.viewmats[i].cpu().numpy(), views.height,
                               views.width).reshape(-1, 3).to(w.pixels.device)[w.pixels]
        silhouette = w.to_image((w.alpha > cfg.silhouette_alpha)[:, None].float())[..., 0] > 0
        target = display(views.images[i], mode=cfg.tonemap).clamp(0, 1)
        valid = (silhouette & views.masks[i])[crop]
        if valid.any():  # a view without a valid pixel (a single-sided asset seen from behind)
            out.append(_ViewData(w, dirs, target[crop], valid, crop))  # has no loss: its masked
    if not out:                                                      # means would be NaN
        raise ValueError("joint_ir: no input view has a foreground pixel the asset covers")
    return out


def _initial_env(views: SceneViews, cfg: JointIRConfig) -> Tensor:
    """Constant log radiance explaining the mean foreground radiance with albedo init_albedo."""
    mean_rad = views.images[views.masks].mean().clamp_min(1e-3)
    level = float(mean_rad) / cfg.init_albedo
    return torch.full((cfg.env_height, 2 * cfg.env_height, 3), math.log(level), device=views.images.device)


def _render_batch(batch: list[_ViewData], features: Tensor, env: Tensor,
                  ops) -> tuple[Tensor, Tensor]:
    """Shaded radiance [B, h, w, 3] (over black) and un-premultiplied maps [B, h, w, 5], cropped.

    The environment is prefiltered once and all the batch's pixels are shaded together.
    """
    alphas = [vd.weights.alpha.clamp_min(1e-8)[:, None] for vd in batch]
    maps = [vd.weights.render(features) / a for vd, a in zip(batch, alphas)]  # weighted means
    flat = torch.cat(maps)
    rad = split_sum(flat[:, :3], flat[:, 3:4], flat[:, 4:5],
                    torch.cat([vd.weights.normals for vd in batch]),
                    torch.cat([vd.view_dirs for vd in batch]), prefilter_learnable(env, ops))
    rads = rad.split([len(m) for m in maps])
    images = [vd.cropped(r * a) for vd, r, a in zip(batch, rads, alphas)]
    map_images = [vd.cropped(m) for vd, m in zip(batch, maps)]
    return torch.stack(images), torch.stack(map_images)


def _step_loss(batch: list[_ViewData], params: dict, cfg: JointIRConfig, ops) -> tuple[Tensor, dict]:
    """Total loss over a batch of views and its parts (floats)."""
    features = torch.cat([torch.sigmoid(params["albedo"]), torch.sigmoid(params["roughness"]),
                          torch.sigmoid(params["metallic"])], dim=-1)
    env = torch.exp(params["log_env"])
    rads, maps = _render_batch(batch, features, env, ops)
    pred = display(rads, mode=cfg.tonemap)
    target = torch.stack([vd.target for vd in batch])
    loss, parts = photometric_loss(pred, target, cfg.lambda_dssim)
    valid = torch.stack([vd.valid for vd in batch])
    priors = {
        "albedo_smooth": (cfg.lambda_albedo_smooth, lambda: edge_aware_smoothness(
            maps[..., :3], valid, target, cfg.smooth_gamma)),
        "roughness_smooth": (cfg.lambda_roughness_smooth, lambda: edge_aware_smoothness(
            maps[..., 3:4], valid, target, cfg.smooth_gamma)),
        "metallic_smooth": (cfg.lambda_metallic_smooth, lambda: edge_aware_smoothness(
            maps[..., 4:5], valid, target, cfg.smooth_gamma)),
        "metallic": (cfg.lambda_metallic, lambda: maps[..., 4][valid].mean()),
        "env_white": (cfg.lambda_env_white, lambda: white_light_prior(env)),
    }
    for name, (weight, term) in priors.items():
        if weight > 0:
            value = term()
            loss = loss + weight * value
            parts[name] = float(value.detach())
    parts["loss"] = float(loss.detach())
    return loss, parts


def fit_materials(asset: Gaussians2D, views: SceneViews, cfg: JointIRConfig, *,
                  progress: bool = False) -> tuple[Gaussians2D, Tensor, dict]:
    """Joint optimisation of per-Gaussian materials and the environment (geometry frozen).

    Args:
        asset: The 2DGS asset (N surfels); its geometry and opacities stay fixed.
        views: Input views (linear HDR images, masks, cameras), on the asset's device: the
            optimisation runs there.
        cfg: :class:`JointIRConfig`.
        progress: Log the loss every ``cfg.log_every`` iterations at INFO level.

    Returns:
        ``(asset with PBR logits, learned environment [h, 2h, 3] linear, stats)``; stats
        hold ``loss_first`` / ``loss_final`` (mean over the first / last 10 iterations),
        the last step's loss parts, and timings in seconds.
    """
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    t0 = time.perf_counter()
    asset = asset.detach()
    device = views.images.device
    ops = prefilter_operators(cfg.env_height, 2 * cfg.env_height).to(device)
    data = _prepare_views(asset, views, cfg)
    t_prep = time.perf_counter() - t0
    n = asset.num_gaussians
    params = {
        "albedo": torch.full((n, 3), _logit(cfg.init_albedo), device=device),
        "roughness": torch.full((n, 1), _logit(cfg.init_roughness), device=device),
        "metallic": torch.full((n, 1), _logit(cfg.init_metallic), device=device),
        "log_env": _initial_env(views, cfg),
    }
    lrs = {"albedo": cfg.lr_albedo, "roughness": cfg.lr_roughness, "metallic": cfg.lr_metallic,
           "log_env": cfg.lr_env}
    for p in params.values():
        p.requires_grad_(True)
    optimizer = torch.optim.Adam([{"params": [params[k]], "lr": lrs[k]} for k in params])
    losses, order, parts = [], [], {}
    for step in range(cfg.iterations):
        batch = []
        while len(batch) < min(cfg.views_per_iteration, len(data)):
            if not order:
                order = torch.randperm(len(data), generator=gen).tolist()
            batch.append(data[order.pop()])
        loss, parts = _step_loss(batch, params, cfg, ops)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        losses.append(parts["loss"])
        if progress and ((step + 1) % cfg.log_every == 0 or step == cfg.iterations - 1):
            log.info("joint_ir step %d loss %.4f (l1 %.4f) %.1fs", step + 1, parts["loss"],
                     parts["l1"], time.perf_counter() - t0)
    with torch.no_grad():
        fitted = asset.with_pbr(params["albedo"].detach(), params["roughness"].detach(),
                                params["metallic"].detach())
        env = torch.exp(params["log_env"]).detach()
    k = min(10, len(losses))
    stats = {
        "iterations": cfg.iterations, "num_views": len(data), "num_gaussians": n,
        "loss_first": float(np.mean(losses[:k])) if losses else None,
        "loss_final": float(np.mean(losses[-k:])) if losses else None,
        "last_parts": parts, "seconds_prepare": t_prep,
        "seconds_optimise": time.perf_counter() - t0 - t_prep,
    }
    return fitted, env, stats


def write_test_maps(scene: Scene, fitted: Gaussians2D, out_scene_dir: Path, *,
                    silhouette_alpha: float, split: str = "test") -> int:
    """Renders the learned maps at every view of ``split`` (``test``, or ``train``: the lattice
    views it was fitted on) and writes them (canonical layout).

    Maps are un-premultiplied (composited value / alpha) inside the rendered silhouette
    (``alpha > silhouette_alpha``) and 0 outside; albedo is sRGB-encoded. Rendered on the
    device of ``fitted``, written from the CPU.

    Returns:
        The number of views written.
    """
    views = scene.split_views(split)
    device = fitted.means.device
    for v in views:
        viewmat = torch.as_tensor(v.w2c, dtype=torch.float32, device=device)[None]
        K = torch.as_tensor(v.K, dtype=torch.float32, device=device)[None]
        with torch.no_grad():
            out = render_gaussians(fitted, viewmat, K, scene.width, scene.height, with_pbr=True)
        alpha = out.alpha[0]
        inside = alpha > silhouette_alpha
        maps = torch.where(inside, out.features[0] / alpha.clamp_min(1e-8), 0.0).clamp(0, 1).cpu()
        vdir = Path(out_scene_dir) / split / v.id
        write_material(vdir, "albedo", linear_to_srgb(maps[..., :3]).numpy())
        write_material(vdir, "roughness", maps[..., 3:4].numpy())
        write_material(vdir, "metallic", maps[..., 4:5].numpy())
    return len(views)


def predict_scene(scene: Scene, asset: Gaussians2D, out_scene_dir: Path, cfg: Mapping, *,
                  split: str = "test", progress: bool = False, device: torch.device | str = "cpu") -> dict:
    """Runs the joint inverse-rendering baseline on one scene.

    Args:
        scene: The ground-truth scene (only its ``train`` inputs and ``test`` cameras are read).
        asset: The scene's 2DGS asset (Stage 0 output).
        out_scene_dir: ``<pred>/<scene name>``; ``<split>/<view id>/*.png`` are written there.
        cfg: ``conf/method/joint_ir.yaml`` contents (:class:`JointIRConfig` keys).
        split: The views written: ``test`` (held-out) or ``train`` (the lattice views).
        progress: Log the optimisation.
        device: Where it runs (module docstring); the run's resolved ``device``.

    Returns:
        Stats: ``material_s`` (wall seconds: loading, optimisation and writing),
        ``material_cpu_s`` (process CPU seconds of the same; with one torch thread the
        wall time of an unshared core), ``loss_first``,
        ``loss_final``, ``env_mean`` (learned environment's mean radiance), timings, config.

    Raises:
        gspi.recon.data.ReconInputError: the scene lacks its input views, naming the files.
        ValueError: on an unknown config key.
    """
    options = JointIRConfig.from_mapping(cfg)
    t0, cpu0 = time.perf_counter(), time.process_time()
    device = torch.device(device)
    views = resize_views(load_scene_views(scene, "train").to(device), options.image_size)
    fitted, env, stats = fit_materials(asset.to(device), views, options, progress=progress)
    written = write_test_maps(scene, fitted, Path(out_scene_dir),
                              silhouette_alpha=options.silhouette_alpha, split=split)
    material_s = time.perf_counter() - t0
    return {"material_s": material_s, "material_cpu_s": time.process_time() - cpu0,
            "test_views": written, "env_mean": float(env.mean()),
            **stats, "config": asdict(options)}
