"""Stage III: initialise the PBR logits, then distil the staged targets into them.

    asset_pbr, stats = distill(read_ply(".../point_cloud.ply"), targets, Stage3Config())

Schedule: ``iterations`` Adam steps; each renders ``views_per_iteration`` target views taken in
a fresh seeded permutation every epoch and minimises ``masked_material_loss`` (loss.py). The
mask B_v is fixed: the input asset's rendered silhouette (alpha >= ``silhouette_threshold``)
AND the target's valid pixels. Parameter groups: the three PBR logit tensors (lr ``lr.pbr``),
opacity logits (``lr.opacities``) unless ``freeze_opacity`` (A7/A9), log scales (``lr.scales``)
unless ``freeze_scales`` (A8/A9); every lr decays exponentially to ``lr.final_factor`` of its
start. Means, rotations and SH are never handed to the optimiser ("adaptive geometric
relaxation" with frozen mu, q) and are checked unchanged at the end. ``distill: false`` (A6)
returns the initialisation. ``plateau_tol`` (not in the paper; a CPU budget) ends the schedule
at the first epoch whose mean loss fell by less than that fraction of the previous epoch's; the
lr schedule stays the one of ``iterations``. Deterministic on CPU under ``seed``.
"""
from __future__ import annotations

import logging
import time

import torch

from gspi.gaussians.model import Gaussians2D
from gspi.stage3.config import Stage3Config
from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from gspi.stage3.init import blend_base_color, initialize_pbr
from gspi.stage3.loss import PROPERTIES, masked_material_loss
from gspi.stage3.render import render_base_color, render_geometry, render_materials
from gspi.stage3.targets import StagedTargets

log = logging.getLogger(__name__)


def trainable_groups(asset: Gaussians2D, cfg: Stage3Config) -> list[dict]:
    """Adam parameter groups (``requires_grad_`` set on exactly these tensors)."""
    groups = [{"name": "pbr", "lr": cfg.lr.pbr,
               "params": [asset.albedo_logits, asset.roughness_logits, asset.metallic_logits]}]
    if not cfg.freeze_opacity:
        groups.append({"name": "opacities", "lr": cfg.lr.opacities, "params": [asset.opacity_logits]})
    if not cfg.freeze_scales:
        groups.append({"name": "scales", "lr": cfg.lr.scales, "params": [asset.log_scales]})
    for group in groups:
        for p in group["params"]:
            p.requires_grad_(True)
    return groups


def view_schedule(num_views: int, iterations: int, per_iteration: int, seed: int) -> list[list[int]]:
    """Views of each iteration: consecutive chunks of seeded permutations, one per epoch."""
    gen = torch.Generator().manual_seed(seed)
    order: list[int] = []
    while len(order) < iterations * per_iteration:
        order += torch.randperm(num_views, generator=gen).tolist()
    return [order[i * per_iteration:(i + 1) * per_iteration] for i in range(iterations)]


def epoch_length(num_views: int, per_iteration: int) -> int:
    """Iterations in one epoch of ``view_schedule`` (every view once)."""
    return -(-num_views // per_iteration)


def plateaued(epoch_losses: list[float], tol: float) -> bool:
    """Whether the last epoch's mean loss fell by less than ``tol`` of the one before (a rise counts)."""
    if len(epoch_losses) < 2:
        return False
    before, last = epoch_losses[-2], epoch_losses[-1]
    return before - last < tol * abs(before)


def harmonized_albedo_targets(asset: Gaussians2D, albedo_srgb: torch.Tensor, w2c, K, width: int, height: int,
                              gain, cfg: Stage3Config) -> torch.Tensor:
    """Staged albedo targets with the same SH-DC harmonisation as the initialisation.

    ``A_v <- srgb((1 - beta) lin(A_v) + beta clamp(g C_v, 0, 1))`` where ``C_v`` is the input
    asset's rendered SH degree-0 base colour in view v and ``g`` the initialisation's gain, so
    the distillation keeps what the initialisation blended in instead of undoing it.
    """
    base = render_base_color(asset.detach(), w2c, K, width, height, backend=cfg.backend).to(albedo_srgb)
    gain_t = torch.as_tensor(gain, dtype=albedo_srgb.dtype, device=albedo_srgb.device)
    blended = blend_base_color(srgb_to_linear(albedo_srgb), base, gain_t, cfg.init.sh_harmonize, cfg.init.sh_gain)
    return linear_to_srgb(blended.clamp(0.0, 1.0))


def distill(asset: Gaussians2D, targets: StagedTargets, cfg: Stage3Config, *,
            progress: bool = False) -> tuple[Gaussians2D, dict]:
    """Initialisation + (if ``cfg.distill``) masked differentiable distillation.

    Args:
        asset: the input 2DGS asset (not modified).
        targets: staged per-view targets (their cameras are the views rendered).
        cfg: Stage III config.
        progress: show a tqdm bar.

    Returns:
        (the PBR asset, stats: "init" (initialize_pbr stats), "losses" [[iteration, loss], ...]
        every ``log_every`` and at the end, "final_terms" (last loss terms), "seconds_init",
        "seconds_distill", "seconds_per_iteration", "iterations" (run: fewer than ``cfg.iterations``
        when ``cfg.plateau_tol`` stopped it, "stopped_on_plateau"), "epoch_losses" (each finished
        epoch's mean loss; with ``plateau_tol`` only), "mask_pixels",
        "trainable" (group names), "num_gaussians").

    Raises:
        ValueError: if the mask is empty.
        RuntimeError: if means or rotations changed (a bug: they are never optimised).
    """
    t0 = time.perf_counter()
    t = targets.tensors(asset.device)
    K, w2c = t["K"].to(asset.means), t["w2c"].to(asset.means)
    alpha, depth = render_geometry(asset.detach(), w2c, K, targets.width, targets.height, backend=cfg.backend)
    out, init_stats = initialize_pbr(asset, targets, cfg, depth=depth)
    mask = (alpha >= cfg.loss.silhouette_threshold) & t["valid"]
    stats = {"init": init_stats, "num_gaussians": asset.num_gaussians, "mask_pixels": int(mask.sum()),
             "seconds_init": time.perf_counter() - t0, "losses": [], "final_terms": {}, "iterations": 0,
             "seconds_distill": 0.0, "seconds_per_iteration": None, "trainable": []}
    if not cfg.distill or cfg.iterations == 0:
        return out, stats
    if not mask.any():
        raise ValueError("Stage III mask is empty: the asset's silhouette and the valid targets do not overlap")
    means0, quats0 = out.means.clone(), out.quats.clone()
    groups = trainable_groups(out, cfg)
    stats["trainable"] = [g["name"] for g in groups]
    optimizer = torch.optim.Adam(groups, eps=1e-15)
    gamma = cfg.lr.final_factor ** (1.0 / max(cfg.iterations, 1))
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimizer, gamma)
    target_maps = {p: t[p].to(asset.means) for p in PROPERTIES}
    if cfg.init.harmonize_targets and cfg.init.sh_harmonize > 0:
        target_maps["albedo"] = harmonized_albedo_targets(asset, target_maps["albedo"], w2c, K, targets.width,
                                                          targets.height, init_stats["sh_gain"], cfg)
    schedule = view_schedule(targets.num_views, cfg.iterations, cfg.views_per_iteration, cfg.seed)
    steps = range(cfg.iterations)
    if progress:
        from tqdm import tqdm
        steps = tqdm(steps, desc="stage3", unit="it")
    t1 = time.perf_counter()
    epoch = epoch_length(targets.num_views, cfg.views_per_iteration)
    epoch_losses: list[float] = []  # mean loss of each finished epoch (plateau_tol)
    running, done = [], 0
    for it in steps:
        views = [v for v in schedule[it] if mask[v].any()]
        if views:
            idx = torch.tensor(views, device=asset.device)
            pred = render_materials(out, w2c[idx], K[idx], targets.width, targets.height, backend=cfg.backend)
            loss, terms = masked_material_loss(pred, {p: m[idx] for p, m in target_maps.items()}, mask[idx],
                                               weights=cfg.weights, ssim_lambda=cfg.loss.ssim_lambda)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            scheduler.step()
            running.append(float(loss.detach()))
            if (it + 1) % cfg.log_every == 0 or it + 1 == cfg.iterations:
                stats["losses"].append([it + 1, float(loss.detach())])
                log.info("stage3 it %d loss %.5f", it + 1, float(loss.detach()))
            stats["final_terms"] = terms
        done = it + 1
        if cfg.plateau_tol is not None and done % epoch == 0 and running:
            epoch_losses.append(sum(running) / len(running))
            running = []
            if plateaued(epoch_losses, cfg.plateau_tol):
                log.info("stage3 stopped at it %d: the epoch's mean loss %.5f fell by less than %g of %.5f",
                         done, epoch_losses[-1], cfg.plateau_tol, epoch_losses[-2])
                if stats["losses"] and stats["losses"][-1][0] != done:
                    stats["losses"].append([done, float(loss.detach())])
                break
    out = out.detach()
    if not (torch.equal(out.means, means0) and torch.equal(out.quats, quats0)):
        raise RuntimeError("Stage III changed frozen means or rotations")
    stats["iterations"] = done
    stats["epoch_losses"] = epoch_losses
    stats["stopped_on_plateau"] = done < cfg.iterations
    stats["seconds_distill"] = time.perf_counter() - t1
    stats["seconds_per_iteration"] = stats["seconds_distill"] / max(done, 1)
    return out, stats
