"""Stage 0 of one scene, and the one ``recon.json`` every caller writes.

``gspi-recon`` (one scene into a folder), ``gspi-run ... assets=null`` (the sweep's cache,
gspi/run/assets.py) and the reconstructed Stage II pool (gspi/recon/reconstructed_pool.py) all
call :func:`reconstruct_scene`, so an asset reconstructed by any of them carries the same record:

    format, scene, scene_dir, train_split, image_size, num_input_views,
    num_gaussians, sh_degree, iterations,
    seconds {init, train, per_iteration, total},   total = init + train (the asset's cost)
    display_transform, loss, train {metrics}, test {metrics, per_view} | None, test_initial | None,
    the trainer's densification stats (strategy, opacity_resets, ...), history,
    threads, load_average, config

Callers add what only they know (gspi-recon: ``ply``, ``wall_seconds``; the pool: its
lattice statistics).
"""
from __future__ import annotations

import math
import os
import time
from typing import Any, Mapping, Optional

import torch

from eval.common.layout import Scene
from gspi.gaussians.model import Gaussians2D
from gspi.recon.data import SceneViews, load_scene_views
from gspi.recon.init import init_gaussians
from gspi.recon.trainer import ReconConfig, display_transform_name, evaluate_views, fit_gaussians

FORMAT = "gspi-recon/2"


def finite(obj):
    """JSON-safe copy: non-finite floats become None."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    return obj


def loss_description(cfg: ReconConfig) -> str:
    loss = cfg.loss
    return (f"(1-{loss.lambda_dssim}) L1 + {loss.lambda_dssim} D-SSIM on display values, black background; "
            f"+ {loss.lambda_mask} |alpha - mask|; + {loss.lambda_normal} 2DGS normal consistency from "
            f"iteration {loss.normal_from_iter}; no depth distortion")


def _summary(metrics: Optional[dict]) -> Optional[dict]:
    return None if metrics is None else {k: v for k, v in metrics.items() if k != "per_view"}


def reconstruct_scene(scene: Scene, recon_cfg: Mapping[str, Any] | ReconConfig, *, device: str = "cpu",
                      train_split: str = "train", eval_split: Optional[str] = None,
                      views: Optional[SceneViews] = None) -> tuple[Gaussians2D, dict]:
    """Fits ``scene``'s ``train_split`` views; returns (asset on the CPU, its recon.json record).

    With ``eval_split`` (and views in it) the record holds held-out metrics before and after.
    ``views``: the ``train_split`` views when the caller has loaded them already.
    """
    rcfg = recon_cfg if isinstance(recon_cfg, ReconConfig) else ReconConfig.from_dict(dict(recon_cfg))
    if not 0 <= rcfg.sh_degree <= 3:
        raise ValueError(f"recon.sh_degree must be in 0..3, got {rcfg.sh_degree}")
    dev = torch.device(device)
    views = (views if views is not None else load_scene_views(scene, train_split)).to(dev)
    test = load_scene_views(scene, eval_split).to(dev) if eval_split and scene.views.get(eval_split) else None
    t0 = time.perf_counter()
    gen = torch.Generator().manual_seed(rcfg.seed)
    init = init_gaussians(views, rcfg.init.num_points, rcfg.sh_degree, init_opacity=rcfg.init.opacity,
                          scale_factor=rcfg.init.scale_factor, generator=gen).to(dev)
    t_init = time.perf_counter() - t0
    initial = evaluate_views(init, test, rcfg.display) if test is not None else None
    result = fit_gaussians(views, rcfg, init=init)
    final = evaluate_views(result.gaussians, test, rcfg.display) if test is not None else None
    stats = dict(result.stats)
    history = stats.pop("history")
    stats.pop("seconds_init")
    t_train = stats.pop("seconds_train")
    record = {
        "format": FORMAT,
        "scene": scene.name,
        "scene_dir": str(scene.root.resolve()),
        "train_split": train_split,
        "image_size": [views.height, views.width],
        "num_input_views": views.num_views,
        "num_gaussians": result.gaussians.num_gaussians,
        "sh_degree": result.gaussians.sh_degree,
        "iterations": rcfg.iterations,
        "seconds": {"init": t_init, "train": t_train, "per_iteration": stats.pop("seconds_per_iteration"),
                    "total": t_init + t_train},
        "display_transform": display_transform_name(rcfg.display),
        "loss": loss_description(rcfg),
        "train": _summary(evaluate_views(result.gaussians, views, rcfg.display)),
        "test": None if final is None else {"split": eval_split, **final},
        "test_initial": _summary(initial),
        **{k: v for k, v in stats.items() if k not in ("iterations", "num_gaussians")},
        "history": history,
        "threads": torch.get_num_threads(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "config": rcfg.to_dict(),
    }
    return result.gaussians.to("cpu"), finite(record)


def reconstruction_seconds(record: Mapping[str, Any]) -> Optional[float]:
    """The asset's cost from a recon.json (``seconds.total``; a float ``seconds`` of the first
    schema, still in old sweep caches, is read as is)."""
    seconds = record.get("seconds")
    return seconds.get("total") if isinstance(seconds, Mapping) else seconds
