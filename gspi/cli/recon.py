"""gspi-recon: Stage 0, fit a 2DGS asset to a canonical scene's input views.

Examples:
    gspi-recon scene=data/small/s000_torus_rough_plastic out=runs/recon/s000
    gspi-recon scene=data/tiny/s000_torus_rough_plastic out=/tmp/r recon=tiny      # seconds
    gspi-recon scene=... out=... recon.iterations=6000 recon.sh_degree=2 recon.densify.impl=builtin

Reads the scene's ``train`` views (``rgb.exr`` linear HDR, ``mask.png``), optimises 2DGS
surfels (gspi/recon/trainer.py) and writes into ``out`` (also Hydra's run dir, with
``.hydra/``; the working directory never changes):

* ``point_cloud.ply``: the asset in the official 2DGS layout (``gspi.gaussians.write_ply``);
* ``recon.json``: the record every Stage 0 caller writes (``gspi.recon.reconstruct``: the same
  schema as gspi-run's reconstruction cache), with held-out metrics on the ``test`` views
  (masked and full-image PSNR / SSIM after the loss's display transform) before and after,
  plus ``ply`` and ``wall_seconds``.

Config: conf/gspi_recon.yaml, conf/recon/{default,tiny}.yaml.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict:
    """Reconstructs ``cfg.scene`` into ``cfg.out``; returns recon.json's content."""
    import torch

    from eval.common.layout import read_scene
    from eval.common.atomic import write_json_atomic
    from gspi.device import resolve_device
    from gspi.gaussians.ply import write_ply
    from gspi.recon.data import ReconInputError
    from gspi.recon.reconstruct import reconstruct_scene

    t0 = time.perf_counter()
    torch.set_num_threads(int(cfg.threads))
    scene_dir, out = Path(cfg.scene), Path(cfg.out)
    if not (scene_dir / "scene.json").is_file():
        raise ReconInputError(f"{scene_dir / 'scene.json'}: file not found (not a canonical scene folder)")
    scene = read_scene(scene_dir)
    eval_split = cfg.get("eval_split")
    if eval_split and not scene.views.get(eval_split):
        log.warning("scene %s has no %r views: no held-out metrics", scene.name, eval_split)
    gaussians, record = reconstruct_scene(scene, OmegaConf.to_container(cfg.recon, resolve=True),
                                          device=resolve_device(cfg.get("device", "cpu")),
                                          train_split=cfg.train_split, eval_split=eval_split)
    ply = out / "point_cloud.ply"
    write_ply(ply, gaussians)
    summary = {**record, "ply": str(ply), "wall_seconds": time.perf_counter() - t0}
    write_json_atomic(out / "recon.json", summary)
    final = summary["test"]
    test_txt = ("no test views" if final is None else "no test view shows the object" if not final["num_views"] else
                f"test PSNR {final['psnr_masked']:.2f} dB masked / {final['psnr_full']:.2f} dB full, "
                f"SSIM {final['ssim_masked']:.4f} masked")
    log.info("%s: %d Gaussians, %d iterations, %.0f s; %s -> %s", scene.name, summary["num_gaussians"],
             summary["iterations"], summary["wall_seconds"], test_txt, out)
    return summary


main = hydra_cli(run, "gspi_recon", path_keys=("scene", "out"))  # paths quoted, stated errors as one line


if __name__ == "__main__":
    main()
