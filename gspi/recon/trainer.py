"""Photometric fitting of a 2DGS asset to a scene's input views (Stage 0).

One input view per iteration (3DGS), in a reshuffled order every epoch; per-parameter
Adam (eps 1e-15) with gsplat's learning rates and exponential decay of the centre
learning rate; SH degree raised by one every ``sh_increase_every`` iterations up to
``sh_degree``; densify / prune by ``gsplat.strategy.DefaultStrategy`` (``strategy.py``).

Loss (on display values, see ``losses.py``): ``(1 - l) L1 + l (1 - SSIM)`` with l = 0.2,
over a black background (the inputs are black outside the object), plus
``lambda_mask * |alpha - mask|`` (clean silhouettes: a dark surface cannot be explained by
missing opacity) and, from ``normal_from_iter`` on, 2DGS's normal-consistency term
``lambda_normal * mean(1 - n_render . n_depth)``. 2DGS's depth-distortion term is not
included: the torch rasterizer does not composite the distortion channel.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from typing import Callable, ClassVar, Optional

import torch
from torch import Tensor

from eval.metrics import masked_psnr, masked_ssim
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import render_gaussians, tile_backend
from gspi.recon.data import SceneViews
from gspi.recon.init import init_gaussians
from gspi.recon.losses import display, normal_consistency, photometric_loss
from gspi.recon.render import render_views
from gspi.recon.strategy import from_params, make_strategy, maybe_reset_opacity, to_params
from gspi.strict_config import dataclass_from_dict

log = logging.getLogger(__name__)


@dataclass
class InitConfig:
    num_points: int = 4000        # surfels sampled on the visual hull

    RANGES: ClassVar[dict] = {"num_points": (1, None), "opacity": (1e-6, 1.0), "scale_factor": (1e-6, None)}
    opacity: float = 0.1          # initial opacity (3DGS / gsplat)
    scale_factor: float = 1.0     # times the 3-NN distance


@dataclass
class LrConfig:
    means: float = 1.6e-4         # times scene_scale (3DGS), decayed exponentially ...
    means_final_factor: float = 0.01  # ... to this fraction at the last iteration
    scales: float = 5e-3
    quats: float = 1e-3
    opacities: float = 5e-2
    sh0: float = 2.5e-3
    shN: float = 1.25e-4          # sh0 / 20


@dataclass
class LossConfig:
    lambda_dssim: float = 0.2
    lambda_mask: float = 0.1
    lambda_normal: float = 0.05
    normal_from_iter: int = 900


@dataclass
class DisplayConfig:
    tonemap: str = "aces"         # eval.common.colorspace.tonemap mode: aces | clamp | reinhard
    exposure_stops: float = 0.0
    srgb: bool = True


@dataclass
class DensifyConfig:
    impl: str = "auto"            # auto | gsplat | builtin (see strategy.py)
    refine_start_iter: int = 250
    refine_stop_iter: int = 1000
    refine_every: int = 100
    reset_every: int = 600
    pause_refine_after_reset: int = 0
    grow_grad2d: float = 0.0002
    grow_scale3d: float = 0.01
    prune_opa: float = 0.005
    prune_scale3d: float = 0.1
    max_gaussians: int = 8000    # soft cap: no growth while at or above it (0 = none)


@dataclass
class ReconConfig:
    name: str = "default"
    iterations: int = 1500
    sh_degree: int = 3
    sh_increase_every: int = 250
    seed: int = 0
    log_every: int = 250
    init: InitConfig = field(default_factory=InitConfig)
    lr: LrConfig = field(default_factory=LrConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    display: DisplayConfig = field(default_factory=DisplayConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)

    # Allowed values, checked by gspi.strict_config at start-up (inclusive; None = open). At
    # least one iteration: an untrained asset would be scored as if it were a reconstruction.
    RANGES: ClassVar[dict] = {"iterations": (1, None), "sh_degree": (0, 3), "sh_increase_every": (1, None),
                              "seed": (0, None), "log_every": (1, None)}

    @classmethod
    def from_dict(cls, data: dict) -> "ReconConfig":
        """Builds the config from plain nested dicts; unknown keys raise ``ValueError``."""
        return dataclass_from_dict(cls, dict(data), "recon")

    def to_dict(self) -> dict:
        return asdict(self)


def scene_scale(viewmats: Tensor) -> float:
    """3DGS's ``cameras_extent``: 1.1 x the largest camera distance from the cameras' mean."""
    from gspi.gaussians.cameras import camera_centers

    c = camera_centers(viewmats.double())
    return float(1.1 * (c - c.mean(0)).norm(dim=-1).max())


def _display_cfg(cfg: DisplayConfig) -> dict:
    return {"mode": cfg.tonemap, "exposure_stops": cfg.exposure_stops, "srgb": cfg.srgb}


def display_transform_name(cfg: DisplayConfig) -> str:
    exp = f" x 2^{cfg.exposure_stops:g}" if cfg.exposure_stops else ""
    return f"eval.common.colorspace.tonemap(mode={cfg.tonemap!r}{exp}, srgb={cfg.srgb}) of linear radiance"


@torch.no_grad()
def evaluate_views(gaussians: Gaussians2D, views: SceneViews, display_cfg: DisplayConfig) -> dict:
    """Held-out image metrics of an asset on ``views`` (black background, display values).

    Returns the means over views of masked PSNR / SSIM (inside the ground-truth mask,
    ``eval.metrics``) and full-image PSNR / SSIM (all pixels; the object on black), plus
    per-view values. Views whose mask is empty (a single-sided card seen from behind, a view
    that misses the object) have nothing to score: they are listed in ``empty_views`` and left
    out of the means, which are None when no view is left.
    """
    per_view, empty = [], []
    dcfg = _display_cfg(display_cfg)
    for i in range(views.num_views):
        if not bool(views.masks[i].any()):
            empty.append(views.ids[i])
            continue
        # the training renderer's backend (recon.render), not gsplat: held-out views score what was fit
        out = render_gaussians(gaussians, views.viewmats[i:i + 1], views.Ks[i:i + 1], views.width,
                               views.height, backend=tile_backend("auto", gaussians.means.device))
        pred = display(out.rgb[0], **dcfg).clamp(0, 1)
        gt = display(views.images[i], **dcfg).clamp(0, 1)
        mask = views.masks[i]
        ones = torch.ones_like(mask)
        per_view.append({
            "view": views.ids[i],
            "psnr_masked": masked_psnr(pred, gt, mask), "psnr_full": masked_psnr(pred, gt, ones),
            "ssim_masked": masked_ssim(pred, gt, mask), "ssim_full": masked_ssim(pred, gt, ones),
            "alpha_iou": float(((out.alpha[0, ..., 0] > 0.5) & mask).sum() / ((out.alpha[0, ..., 0] > 0.5) | mask).sum()),
        })
    keys = ("psnr_masked", "psnr_full", "ssim_masked", "ssim_full", "alpha_iou")
    mean = {k: float(sum(v[k] for v in per_view) / len(per_view)) if per_view else None for k in keys}
    return {**mean, "num_views": len(per_view), "empty_views": empty, "per_view": per_view}


@dataclass
class FitResult:
    gaussians: Gaussians2D
    stats: dict


def _lr_means(cfg: ReconConfig, step: int, scale: float) -> float:
    frac = step / max(cfg.iterations - 1, 1)
    return cfg.lr.means * scale * (cfg.lr.means_final_factor ** frac)


def fit_gaussians(views: SceneViews, cfg: ReconConfig, *, init: Optional[Gaussians2D] = None,
                  callback: Optional[Callable[[int, dict], None]] = None) -> FitResult:
    """Optimises 2DGS surfels to reproduce ``views`` (see the module docstring).

    Args:
        views: the input views (linear HDR ``images``, ``masks``, cameras).
        cfg: :class:`ReconConfig`.
        init: starting surfels; default: :func:`gspi.recon.init.init_gaussians` on the visual hull.
        callback: called as ``callback(step, info)`` after each logged step.

    Returns:
        :class:`FitResult` with the surfels (SH degree ``cfg.sh_degree``) and training stats.
    """
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    t_start = time.perf_counter()
    if init is None:
        init = init_gaussians(views, cfg.init.num_points, cfg.sh_degree, init_opacity=cfg.init.opacity,
                              scale_factor=cfg.init.scale_factor, generator=gen)
    if init.sh_degree != cfg.sh_degree:
        raise ValueError(f"init has SH degree {init.sh_degree}, config asks for {cfg.sh_degree}")
    t_init = time.perf_counter() - t_start
    scale = scene_scale(views.viewmats)
    params = to_params(init)
    lrs = {"means": _lr_means(cfg, 0, scale), "scales": cfg.lr.scales, "quats": cfg.lr.quats,
           "opacities": cfg.lr.opacities, "sh0": cfg.lr.sh0, "shN": cfg.lr.shN}
    optimizers = {k: torch.optim.Adam([{"params": [params[k]], "lr": lr, "name": k}], eps=1e-15)
                  for k, lr in lrs.items()}
    dens = cfg.densify
    strategy, strategy_name = make_strategy(asdict(dens), dens.impl)
    strategy.check_sanity(params, optimizers)
    state = strategy.initialize_state(scene_scale=scale)
    dcfg = _display_cfg(cfg.display)
    gt_display = display(views.images, **dcfg).clamp(0, 1)  # [V, H, W, 3]
    masks_f = views.masks.float()[..., None]
    bg = torch.zeros(1, 3, device=views.images.device)
    order: list[int] = []
    history, resets, capped = [], 0, 0
    t_loop = time.perf_counter()
    for step in range(cfg.iterations):
        if not order:
            order = torch.randperm(views.num_views, generator=gen).tolist()
        v = order.pop()
        sh_deg = min(cfg.sh_degree, step // max(cfg.sh_increase_every, 1))
        optimizers["means"].param_groups[0]["lr"] = _lr_means(cfg, step, scale)
        over_cap = dens.max_gaussians > 0 and len(params["means"]) >= dens.max_gaussians
        out = render_views(params["means"], params["quats"], torch.exp(params["scales"][:, :2]),
                           torch.sigmoid(params["opacities"]), torch.cat([params["sh0"], params["shN"]], 1),
                           sh_deg, views.viewmats[v:v + 1], views.Ks[v:v + 1], views.width, views.height,
                           backgrounds=bg, densify_grad=True)
        strategy.step_pre_backward(params, optimizers, state, step, out.meta)
        pred = display(out.rgb, **dcfg)
        loss, parts = photometric_loss(pred, gt_display[v:v + 1], cfg.loss.lambda_dssim)
        if cfg.loss.lambda_mask > 0:
            mask_l1 = (out.alpha - masks_f[v:v + 1]).abs().mean()
            loss = loss + cfg.loss.lambda_mask * mask_l1
            parts["mask"] = float(mask_l1.detach())
        if cfg.loss.lambda_normal > 0 and step >= cfg.loss.normal_from_iter:
            nc = normal_consistency(out, views.Ks[v:v + 1], views.viewmats[v:v + 1])
            loss = loss + cfg.loss.lambda_normal * nc
            parts["normal"] = float(nc.detach())
        loss.backward()
        if over_cap:  # soft cap: no growth while at or above max_gaussians (pruning goes on)
            out.meta["gradient_2dgs"].grad.zero_()
            if state.get("grad2d") is not None:
                state["grad2d"].zero_()
            capped += 1
        strategy.step_post_backward(params, optimizers, state, step, out.meta, packed=False)
        if maybe_reset_opacity(strategy, params, optimizers, state, step):
            resets += 1
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        if (step + 1) % cfg.log_every == 0 or step == cfg.iterations - 1:
            info = {"step": step + 1, "loss": float(loss.detach()), **parts, "num_gaussians": len(params["means"]),
                    "sh_degree": sh_deg, "seconds": time.perf_counter() - t_loop}
            history.append(info)
            log.info("step %d loss %.4f (l1 %.4f) N=%d sh=%d %.1fs", step + 1, info["loss"], parts["l1"],
                     info["num_gaussians"], sh_deg, info["seconds"])
            if callback is not None:
                callback(step + 1, info)
    t_train = time.perf_counter() - t_loop
    g = from_params(params)
    stats = {
        "iterations": cfg.iterations, "num_gaussians": g.num_gaussians, "num_gaussians_init": init.num_gaussians,
        "seconds_init": t_init, "seconds_train": t_train,
        "seconds_per_iteration": t_train / max(cfg.iterations, 1), "scene_scale": scale,
        "strategy": strategy_name, "opacity_resets": resets, "steps_at_cap": capped, "history": history,
    }
    return FitResult(g, stats)
