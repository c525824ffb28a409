"""Table 2's measure: Stage II on the GT point cloud, scored in the 32 lattice views.

For each scene: predictions for every point (``subset_prediction``: DDIM on the whole cloud, or
on a seeded subset with 1-NN fill), scattered back into the per-view maps through the stored
source pixels, and scored against the GT maps (``albedo.png``, ``roughness.png``,
``metallic.png``) with ``eval.metrics`` (masked PSNR / SSIM / LPIPS; mask = the pixels that
received a point). The no-decomposition baseline: albedo = the observed colour
``sRGB(clamp(rgb_linear))`` (the Top-RGB), roughness and metallic = the mean of the training
points' values (the L2-optimal constants). Per view and channel scores are averaged over the 32
views, then over scenes; "avg" is the mean of the three channels. A per-view PSNR is capped at
``PSNR_CAP_DB`` (an exact match would be inf). ``point_metal_iou``: IoU of the metal points.

Used by the validation while training (``gspi.stage2.validate``) and the one CLI
(``python -m gspi.stage2.evaluate_points``), which a study's predictors share.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np
import torch

from gspi.data.gt_maps import read_gt_view_maps
from gspi.point_cloud import nearest_fill, scatter_pixel_values
from gspi.stage2.data import PointDataConfig, ScenePoints, whole_scene_inputs
from gspi.stage2.normalize import pbr_from_model

log = logging.getLogger(__name__)
CHANNELS = {"albedo": slice(0, 3), "roughness": slice(3, 4), "metallic": slice(4, 5)}
PSNR_CAP_DB = 60.0
METRICS = ("psnr", "ssim", "lpips")


@dataclass(frozen=True)
class PointSampling:
    """How a model's predictions are drawn for the measure (``ValidationConfig`` has these fields)."""

    num_steps: int = 50              # DDIM steps
    max_points: Optional[int] = None  # per scene: seeded subset + 1-NN fill; None = every point
    seed: int = 0
    num_samples: int = 1             # DDIM samples (seeds seed, seed+1, ...) averaged per point (stage2.inference.num_samples)
    guidance_scale: float = 1.0      # classifier-free guidance (stage2.inference.guidance_scale; 1 = off)
    patch_points: Optional[int] = None  # k-NN patches of this many points (stage2.inference.patch_points); None = whole cloud
    patch_coverage: float = 2.0      # patches per point on average (stage2.inference.patch_coverage)


def scatter_to_views(values: np.ndarray, scene: ScenePoints) -> tuple[np.ndarray, np.ndarray]:
    """Per-point values [P, C] -> per-view maps [V, H, W, C] and mask [V, H, W] (pixels hit)."""
    cams = scene.cameras
    return scatter_pixel_values(scene.view, scene.pixel, values, height=cams.height, width=cams.width,
                                num_views=len(cams.K))


def score_maps(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray, lpips_net) -> dict[str, dict[str, float]]:
    """Scores [V, H, W, 5] predictions: {channel: {metric: mean over views}}."""
    from eval.metrics import masked_lpips, masked_psnr, masked_ssim

    out = {}
    for channel, sl in CHANNELS.items():
        rows = []
        for v in range(len(pred)):
            if not mask[v].any():
                continue
            p, g, m = (torch.from_numpy(pred[v, ..., sl]), torch.from_numpy(gt[v, ..., sl]),
                       torch.from_numpy(mask[v]))
            rows.append((min(masked_psnr(p, g, m), PSNR_CAP_DB), masked_ssim(p, g, m),
                         masked_lpips(p, g, m, net=lpips_net)))
        out[channel] = dict(zip(METRICS, np.mean(rows, axis=0).tolist()))
    return out


def training_constants(train_scenes: list[ScenePoints]) -> tuple[float, float]:
    """Mean roughness and metallic over all training points (the L2-optimal constants)."""
    f0 = np.concatenate([s.f0 for s in train_scenes])
    pbr = pbr_from_model(torch.from_numpy(f0)).numpy()
    return float(pbr[:, 3].mean()), float(pbr[:, 4].mean())


def baseline_prediction(scene: ScenePoints, roughness: float, metallic: float) -> np.ndarray:
    """[P, 5] no-decomposition prediction: albedo = Top-RGB (sRGB), constant roughness/metallic."""
    const = np.broadcast_to(np.array([roughness, metallic], dtype=np.float32), (scene.num_points, 2))
    return np.concatenate([scene.top_rgb, const], axis=1)


def evaluate_scenes(scenes: list[ScenePoints], predict: Callable[[ScenePoints], np.ndarray],
                    baseline: Callable[[ScenePoints], np.ndarray], *, lpips_net=None) -> dict[str, Any]:
    """{"stage2": {scene: scores}, "no_decomposition": {...}, "mean": {method: scores}}."""
    from eval.lpips.net import load_lpips

    net = lpips_net if lpips_net is not None else load_lpips()
    per_scene: dict[str, dict] = {"stage2": {}, "no_decomposition": {}}
    metal_iou: dict[str, dict] = {"stage2": {}, "no_decomposition": {}}
    timings = {}
    for scene in scenes:
        gt = read_gt_view_maps(scene.root)[0]
        t0 = time.perf_counter()
        pred = predict(scene)
        timings[scene.name] = round(time.perf_counter() - t0, 2)
        for method, values in (("stage2", pred), ("no_decomposition", baseline(scene))):
            maps, mask = scatter_to_views(values, scene)
            per_scene[method][scene.name] = score_maps(maps, gt, mask, net)
            metal_iou[method][scene.name] = point_metal_iou(values[:, 4], scene)
        log.info("%s: %d points, predicted in %.1f s; albedo PSNR %.2f (baseline %.2f)", scene.name,
                 scene.num_points, timings[scene.name], per_scene["stage2"][scene.name]["albedo"]["psnr"],
                 per_scene["no_decomposition"][scene.name]["albedo"]["psnr"])
    mean = {m: average_scores(list(s.values())) for m, s in per_scene.items()}
    return {"per_scene": per_scene, "mean": mean, "predict_time_s": timings, "metal_iou": metal_iou}


def point_metal_iou(metallic: np.ndarray, scene: ScenePoints, threshold: float = 0.5) -> float | None:
    """IoU of {metallic > threshold} between a prediction [P] and the GT points (one point per
    lattice pixel, so it is the pixel IoU over the 32 views); None when neither has metal."""
    gt = pbr_from_model(torch.from_numpy(scene.f0[:, 4])).numpy() > threshold
    pred = np.asarray(metallic) > threshold
    union = int(np.count_nonzero(gt | pred))
    return None if union == 0 else float(np.count_nonzero(gt & pred)) / union


def average_scores(scores: list[dict]) -> dict[str, dict[str, float]]:
    """Mean over scenes per channel and metric, plus "avg" = mean over the three channels."""
    out = {c: {m: float(np.mean([s[c][m] for s in scores])) for m in METRICS} for c in CHANNELS}
    out["avg"] = {m: float(np.mean([out[c][m] for c in CHANNELS])) for m in METRICS}
    return out


def subset_prediction(model, scene: ScenePoints, index: int, data_cfg: PointDataConfig,
                      cfg: PointSampling, *, write_chunk: int | None = 32768) -> np.ndarray:
    """[P, 5] PBR of every point of ``scene``: sampled on a seeded subset, 1-NN filled (every
    point when ``cfg.max_points`` is None: Table 2's measure proper). ``cfg``: a
    ``PointSampling`` or anything with its fields (``ValidationConfig``)."""
    from gspi.stage2.sampler import mean_point_pbr

    rng = np.random.default_rng([cfg.seed, index])
    xyz, cond = whole_scene_inputs(scene, data_cfg, rng)
    keep = np.arange(scene.num_points)
    if cfg.max_points is not None and scene.num_points > cfg.max_points:
        keep = np.sort(rng.choice(scene.num_points, cfg.max_points, replace=False))
    feats = scene.prior_grid()
    device = next(model.parameters()).device
    values = mean_point_pbr(model, xyz[keep], cond[keep], None if feats is None else feats.to(device),
                            num_samples=getattr(cfg, "num_samples", 1), seed=cfg.seed, num_steps=cfg.num_steps,
                            frame=scene.frame, write_chunk=write_chunk,
                            guidance_scale=getattr(cfg, "guidance_scale", 1.0),
                            patch_points=getattr(cfg, "patch_points", None),
                            patch_coverage=getattr(cfg, "patch_coverage", 2.0))
    return values if len(keep) == scene.num_points else nearest_fill(scene.xyz[keep], values, scene.xyz)
