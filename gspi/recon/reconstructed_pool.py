"""A Stage II training pool as the paper trains it: conditions from Stage 0 reconstructions.

Paper, "Training vs. Inference Dynamics": "the 32 reference views used by both training and
evaluation are deterministically rasterized ... from the reconstructed Gaussian asset". A
generated pool scene holds the exact renders of its 32 lattice views; a run reads Stage I's
renders of a 2DGS asset fitted to those views, which loses what a surfel asset cannot hold
(mirror reflections: docs/log/stage2.md "End to end, metal is lost in Stage 0's asset"). This
writes, for every scene of a dataset whose ``train`` views are the lattice (a pool, a
``pool_split`` view, a generated benchmark scene):

    <out>/<scene>/                 the scene by symlinks, with its conditions from the asset
                                   (``gspi.data.pool.asset_conditions``: lattice rgb.exr, Top-RGB)
    <out>/<scene>/asset/point_cloud.ply   the Stage 0 asset (``recon=<name>``)
    <out>/<scene>/asset/recon.json        its seconds, surfels and lattice-render statistics
    <out>/<scene>/reconstructed.json      written last: the scene is done
    <out>/splits.json                     the source's splits

GT points, materials, depth and masks stay the scene's own: the target is the truth, only the
conditions are the asset's. Resumable: done scenes are skipped, partial ones redone.

    python -m gspi.recon.reconstructed_pool POOL64 RPOOL64 [--recon fast] [--workers 2]
    python -m gspi.recon.reconstructed_pool POOL64 RPOOL64 --summary   # per-class table
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from eval.common.layout import read_splits
from gspi.data.pool.asset_conditions import LATTICE_SPLIT, write_asset_conditions
from gspi.recon.reconstruct import reconstruction_seconds

log = logging.getLogger(__name__)
DONE_FILE = "reconstructed.json"
FORMAT = "gspi-reconstructed-pool"


def recon_config(name: str, overrides: tuple[str, ...] = ()) -> dict:
    """The resolved ``conf/recon/<name>.yaml`` (gspi-recon's Stage 0 config)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from eval.common.conf import CONF_DIR

    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("gspi_recon", overrides=[f"recon={name}", "scene=unused", "out=unused", *overrides])
    return OmegaConf.to_container(cfg.recon, resolve=True)


def highlight_stats(gt_rgb: np.ndarray, asset_rgb: np.ndarray) -> dict:
    """What the asset's lattice renders keep of the GT renders' bright end (linear radiance)."""
    g, a = gt_rgb.mean(axis=-1), asset_rgb.mean(axis=-1)
    fg = g > 0
    if not fg.any():
        return {"gt_q99": 0.0, "asset_q99": 0.0, "gt_frac_above_1": 0.0, "asset_frac_above_1": 0.0}
    return {"gt_q99": float(np.quantile(g[fg], 0.99)), "asset_q99": float(np.quantile(a[fg], 0.99)),
            "gt_frac_above_1": float((g[fg] > 1).mean()), "asset_frac_above_1": float((a[fg] > 1).mean())}


def display_psnr(gt_rgb: np.ndarray, asset_rgb: np.ndarray) -> float:
    """PSNR of the asset's lattice renders against the GT renders on clamped display values."""
    err = np.mean((np.clip(gt_rgb, 0, 1) - np.clip(asset_rgb, 0, 1)) ** 2)
    return float(10 * np.log10(1.0 / max(err, 1e-12)))


def reconstruct_pool_scene(scene_dir: Path, dst: Path, recon_cfg: dict[str, Any], threads: int = 1) -> dict:
    """Stage 0 on ``scene_dir``'s lattice views, then ``dst`` = the scene with the asset's conditions.

    ``dst/asset/recon.json`` is gspi-recon's record (``gspi.recon.reconstruct``) plus the pool's
    ``pool_format``, ``source``, ``cpu_seconds``, ``lattice_display_psnr`` and ``highlights``."""
    import torch

    from eval.common.layout import read_scene
    from eval.common.atomic import write_json_atomic
    from gspi.gaussians.ply import write_ply
    from gspi.gaussians.lattice_render import render_lattice
    from gspi.recon.data import load_scene_views
    from gspi.recon.reconstruct import reconstruct_scene

    torch.set_num_threads(threads)
    scene_dir, dst = Path(scene_dir).resolve(), Path(dst)
    if dst.exists():
        shutil.rmtree(dst)
    cpu0 = time.process_time()
    scene = read_scene(scene_dir)
    views = load_scene_views(scene, LATTICE_SPLIT)
    # a scene with held-out views (e.g. a probe's pool copy with data.num_test_views) also scores
    # them: evaluation only, the asset is the same bytes (tests/test_reconstructed_pool.py)
    eval_split = "test" if scene.views.get("test") else None
    gaussians, record = reconstruct_scene(scene, recon_cfg, train_split=LATTICE_SPLIT, views=views,
                                          eval_split=eval_split)
    asset_rgb = render_lattice(gaussians, image_size=(scene.height, scene.width)).rgb
    gt_rgb = views.images.numpy()  # the exact lattice renders Stage 0 was fitted to
    write_asset_conditions(scene_dir, asset_rgb, dst)
    write_ply(dst / "asset" / "point_cloud.ply", gaussians)
    info = {**record, "pool_format": FORMAT, "source": str(scene_dir),
            "cpu_seconds": round(time.process_time() - cpu0, 2),
            "lattice_display_psnr": round(display_psnr(gt_rgb, asset_rgb), 3),
            "highlights": highlight_stats(gt_rgb, asset_rgb)}
    write_json_atomic(dst / "asset" / "recon.json", info)
    write_json_atomic(dst / DONE_FILE, {"scene": scene.name, "recon_seconds": record["seconds"]["total"]})
    return info


def _worker(args: tuple) -> dict:
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # before reconstruct_pool_scene imports torch
    return reconstruct_pool_scene(*args)


def reconstruct_pool(src: str | Path, out: str | Path, *, recon: str = "fast", workers: int = 1,
                     overrides: tuple[str, ...] = ()) -> list[dict]:
    """Every scene of ``src``'s splits reconstructed into ``out`` (module docstring)."""
    src, out = Path(src), Path(out)
    splits = read_splits(src)  # eval.common.layout: names the file and the problem
    names = [n for split in ("train", "val", "test") for n in splits.get(split, [])]
    cfg = recon_config(recon, overrides)
    out.mkdir(parents=True, exist_ok=True)
    todo = [n for n in names if not (out / n / DONE_FILE).is_file()]
    log.info("%s: %d scenes, %d to reconstruct (recon=%s, %d workers)", src, len(names), len(todo), recon, workers)
    jobs = [(src / n, out / n, cfg, 1) for n in todo]
    done = []
    with ProcessPoolExecutor(workers) if workers > 1 else nullcontext() as pool:
        for info in (pool.map if pool else map)(_worker, jobs):
            done.append(info)
            log.info("%s: %.0f s, %d surfels, lattice %.2f dB", info["scene"], info["seconds"]["total"],
                     info["num_gaussians"], info["lattice_display_psnr"])
    (out / "splits.json").write_text(json.dumps(splits, indent=1) + "\n")
    (out / "reconstructed_pool.json").write_text(json.dumps(
        {"format": FORMAT, "source": str(src.resolve()), "recon": recon, "overrides": list(overrides),
         "recon_config": cfg, "scenes": len(names)}, indent=1) + "\n")
    return done


def summary_table(out: str | Path) -> str:
    """Markdown: per material class, what the assets keep of the bright end, and their cost."""
    rows: dict[str, list[dict]] = {}
    for path in sorted(Path(out).glob("*/asset/recon.json")):
        info = json.loads(path.read_text())
        gen = json.loads((path.parent.parent / "scene.json").read_text()).get("generator", {})
        cls = gen.get("material", {}).get("class", "unclassed")
        rows.setdefault(cls, []).append(info)
    lines = ["| class | scenes | GT px > 1 | asset px > 1 | GT q99 | asset q99 | lattice dB | recon s |",
             "|---|---|---|---|---|---|---|---|"]
    med = lambda xs: float(np.median(xs))  # noqa: E731
    for cls, infos in sorted(rows.items()):
        h = [i["highlights"] for i in infos]
        lines.append(f"| {cls} | {len(infos)} | {100 * med([x['gt_frac_above_1'] for x in h]):.2f} % | "
                     f"{100 * med([x['asset_frac_above_1'] for x in h]):.2f} % | "
                     f"{med([x['gt_q99'] for x in h]):.3f} | {med([x['asset_q99'] for x in h]):.3f} | "
                     f"{med([i['lattice_display_psnr'] for i in infos]):.2f} | {med([reconstruction_seconds(i) for i in infos]):.0f} |")
    return "\n".join(lines) + "\n(medians over the class's scenes)\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path, help="dataset folder whose train views are the lattice (a pool view)")
    parser.add_argument("out", type=Path)
    parser.add_argument("--recon", default="fast", help="conf/recon/<name>.yaml (default: fast, the demo's)")
    parser.add_argument("--workers", type=int, default=1, help="scenes in parallel, one thread each")
    parser.add_argument("overrides", nargs="*", help="recon overrides, e.g. recon.iterations=300")
    parser.add_argument("--summary", action="store_true", help="print the per-class table of OUT and stop")
    args = parser.parse_intermixed_args(argv)  # overrides may follow --recon
    if args.summary:
        print(summary_table(args.out))
        return
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    reconstruct_pool(args.src, args.out, recon=args.recon, workers=args.workers, overrides=tuple(args.overrides))


if __name__ == "__main__":
    from eval.common.errors import run_command

    run_command(main)  # a stated error or Ctrl-C: one line (exit 2 / 130)
