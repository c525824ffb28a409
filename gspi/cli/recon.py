"""gspi-recon: Stage 0, fit a 2DGS asset to a canonical scene's input views.

Examples:
    gspi-recon scene=data/small/s000_torus_rough_plastic out=runs/recon/s000
    gspi-recon scene=data/tiny/s000_torus_rough_plastic out=/tmp/r recon=tiny      # seconds
    gspi-recon scene=... out=... recon.iterations=6000 recon.sh_degree=2 recon.densify.impl=builtin

Reads the scene's ``train`` views (``rgb.exr`` linear HDR, ``mask.png``), optimises 2DGS
surfels (gspi/recon/trainer.py) and writes into ``out`` (also Hydra's run dir, with
``.hydra/``; the working directory never changes):

* ``point_cloud.ply``: the asset in the official 2DGS layout (``gspi.gaussians.write_ply``);
* ``recon.json``: held-out metrics on the ``test`` views (masked and full-image PSNR / SSIM
  after the loss's display transform), the same before training, number of Gaussians,
  iterations, wall seconds, the config and the densification strategy used.

Config: conf/gspi_recon.yaml, conf/recon/{default,tiny}.yaml.
"""
from __future__ import annotations

import logging
import math
import os
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.cli_entry import hydra_cli

log = logging.getLogger(__name__)
# Absolute: a relative config_path resolves as a Python package under console scripts.


def _finite(obj):
    """JSON-safe copy: non-finite floats become None."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def run(cfg: DictConfig) -> dict:
    """Reconstructs ``cfg.scene`` into ``cfg.out``; returns recon.json's content."""
    import torch

    from eval.layout import read_scene, write_json_atomic
    from gspi.gaussians.ply import write_ply
    from gspi.device import resolve_device
    from gspi.recon.data import ReconInputError, load_scene_views
    from gspi.recon.init import init_gaussians
    from gspi.recon.trainer import ReconConfig, display_transform_name, evaluate_views, fit_gaussians

    t0 = time.perf_counter()
    torch.set_num_threads(int(cfg.threads))
    rcfg = ReconConfig.from_dict(OmegaConf.to_container(cfg.recon, resolve=True))
    if rcfg.sh_degree < 0 or rcfg.sh_degree > 3:
        raise ValueError(f"recon.sh_degree must be in 0..3, got {rcfg.sh_degree}")
    scene_dir, out = Path(cfg.scene), Path(cfg.out)
    if not (scene_dir / "scene.json").is_file():
        raise ReconInputError(f"{scene_dir / 'scene.json'}: file not found (not a canonical scene folder)")
    scene = read_scene(scene_dir)
    device = resolve_device(cfg.get("device", "cpu"))
    views = load_scene_views(scene, cfg.train_split).to(device)
    eval_split = cfg.get("eval_split")
    test = None
    if eval_split and scene.views.get(eval_split):
        test = load_scene_views(scene, eval_split).to(device)
    elif eval_split:
        log.warning("scene %s has no %r views: no held-out metrics", scene.name, eval_split)

    gen = torch.Generator().manual_seed(rcfg.seed)
    t_init = time.perf_counter()
    init = init_gaussians(views, rcfg.init.num_points, rcfg.sh_degree, init_opacity=rcfg.init.opacity,
                          scale_factor=rcfg.init.scale_factor, generator=gen).to(device)
    t_init = time.perf_counter() - t_init
    initial = evaluate_views(init, test, rcfg.display) if test is not None else None
    result = fit_gaussians(views, rcfg, init=init)
    ply = out / "point_cloud.ply"
    write_ply(ply, result.gaussians)
    final = evaluate_views(result.gaussians, test, rcfg.display) if test is not None else None
    train_eval = evaluate_views(result.gaussians, views, rcfg.display)
    stats = dict(result.stats)
    history = stats.pop("history")
    stats.pop("seconds_init")
    summary = {
        "scene": scene.name,
        "scene_dir": str(scene_dir.resolve()),
        "ply": str(ply),
        "image_size": [views.height, views.width],
        "num_input_views": views.num_views,
        "num_gaussians": result.gaussians.num_gaussians,
        "sh_degree": result.gaussians.sh_degree,
        "iterations": rcfg.iterations,
        "wall_seconds": None,  # set below
        "seconds": {"init": t_init, "train": stats.pop("seconds_train"),
                    "per_iteration": stats.pop("seconds_per_iteration")},
        "display_transform": display_transform_name(rcfg.display),
        "loss": (f"(1-{rcfg.loss.lambda_dssim}) L1 + {rcfg.loss.lambda_dssim} D-SSIM on display values, black "
                 f"background; + {rcfg.loss.lambda_mask} |alpha - mask|; + {rcfg.loss.lambda_normal} 2DGS normal "
                 f"consistency from iteration {rcfg.loss.normal_from_iter}; no depth distortion"),
        "test": None if final is None else {"split": eval_split, **final},
        "test_initial": None if initial is None else {k: v for k, v in initial.items() if k != "per_view"},
        "train": {k: v for k, v in train_eval.items() if k != "per_view"},
        **{k: v for k, v in stats.items() if k not in ("iterations", "num_gaussians")},
        "history": history,
        "threads": torch.get_num_threads(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "config": rcfg.to_dict(),
    }
    summary["wall_seconds"] = time.perf_counter() - t0
    summary = _finite(summary)
    write_json_atomic(out / "recon.json", summary)
    test_txt = ("no test views" if final is None else
                f"test PSNR {final['psnr_masked']:.2f} dB masked / {final['psnr_full']:.2f} dB full, "
                f"SSIM {final['ssim_masked']:.4f} masked")
    log.info("%s: %d Gaussians, %d iterations, %.0f s; %s -> %s", scene.name, summary["num_gaussians"],
             rcfg.iterations, summary["wall_seconds"], test_txt, out)
    return summary


main = hydra_cli(run, "gspi_recon", path_keys=("scene", "out"))  # paths quoted, stated errors as one line


if __name__ == "__main__":
    main()
