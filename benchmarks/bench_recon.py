"""Times Stage 0 (gspi-recon) training iterations at 64 and 128 px.

One iteration = render one input view (tile 2DGS rasterizer, backend auto: numba
compositing on CPU; SH degree 3) + L1/D-SSIM + mask + normal-consistency loss + backward +
densification bookkeeping + Adam on every tensor. Surfels come from the visual-hull
initialisation with a fixed count (no growth while timed), so the numbers are
per-iteration costs at that many surfels; a full run's time is about iterations x the cost
at its mean surfel count (recon.json reports both).

Scenes: one generated scene per size (gspi-data tiny recipe, torus, written to a temp
folder), or --scene DIR for an existing scene at its own size.

Run: PYTHONPATH=. python benchmarks/bench_recon.py [--sizes 64 128] [--surfels 3000 8000] [--iters 30]
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import torch

from benchmarks.common import machine

REPO = Path(__file__).resolve().parents[1]


def generate_scene(out: Path, size: int) -> Path:
    from hydra import compose, initialize_config_dir

    from eval.common.argv import apply_aliases
    from gspi.cli.data import run

    overrides = ["preset=tiny", f"out={out}", "seed=0", "data.num_train_scenes=1", "data.num_val_scenes=0",
                 "data.num_test_scenes=0", f"data.image_size={size}", "data.env_height=32", "data.num_test_views=1",
                 "data.num_val_views=0", "data.num_relight_envs=1", "data.contact_sheets=false",
                 "data.point_clouds=false"]
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        run(compose("gspi_data", overrides=apply_aliases(overrides, "gspi_data")))
    return next(p for p in out.iterdir() if (p / "scene.json").is_file())


def time_iterations(scene: Path, surfels: int, iters: int) -> tuple[float, int, int]:
    from gspi.recon.data import load_scene_views
    from gspi.recon.trainer import ReconConfig, fit_gaussians

    views = load_scene_views(scene)
    cfg = ReconConfig.from_dict({
        "iterations": iters + 5, "sh_degree": 3, "sh_increase_every": 1, "log_every": 10**9,
        "init": {"num_points": surfels},
        "loss": {"normal_from_iter": 0},
        "densify": {"refine_start_iter": 10**9, "refine_stop_iter": 10**9},  # bookkeeping only
    })
    # the first 5 iterations warm up; time the rest from the recorded total
    warm = fit_gaussians(views, ReconConfig.from_dict({**cfg.to_dict(), "iterations": 5}))
    full = fit_gaussians(views, cfg, init=None)
    per_iter = (full.stats["seconds_train"] - warm.stats["seconds_train"]) / iters
    return per_iter, full.gaussians.num_gaussians, views.width


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--surfels", type=int, nargs="+", default=[3000, 8000])
    parser.add_argument("--iters", type=int, default=30)
    parser.add_argument("--scene", type=Path, default=None, help="existing scene folder (its own size)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(machine())
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        scenes = [args.scene] if args.scene else [generate_scene(Path(tmp) / f"s{s}", s) for s in args.sizes]
        for scene in scenes:
            for n in args.surfels:
                per_iter, count, size = time_iterations(scene, n, args.iters)
                print(f"{size}x{size} px, {count} surfels, SH 3: {per_iter:.3f} s/iteration "
                      f"({args.iters} iterations; default 1500 iterations ~ {1500 * per_iter / 60:.1f} min)")
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
