"""Speed of the procedural benchmark generator (gspi-data).

    PYTHONPATH=. python benchmarks/bench_data.py                 # tracer rays/s + 2 small scenes
    PYTHONPATH=. python benchmarks/bench_data.py --scenes 0      # the whole small preset (22)
    PYTHONPATH=. python benchmarks/bench_data.py --preset tiny --scenes 0

Prints the machine (CPU model, cores, torch threads), then
* sphere tracing alone: rays/s per shape family (128 x 128, 8 lattice views batched, 1 thread);
* generation: seconds per scene and end-to-end rays/s (tracing + materials + split-sum shading +
  file writing + relit GT + point cloud + contact sheet) for the chosen preset, and the
  extrapolated time of the whole preset.
"""
from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from eval.views import pixel_rays
from gspi.data.generate import BenchmarkConfig, generate_dataset
from gspi.data.lattice import lattice_cameras
from gspi.data.procedural.sdf_shapes import FAMILIES, ShapeSDF, sample_shape
from gspi.data.procedural.sphere_trace import sphere_trace

REPO = Path(__file__).resolve().parents[1]


def machine() -> str:
    model = platform.processor() or "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{model}; {os.cpu_count()} cores; torch {torch.__version__}, "
            f"{torch.get_num_threads()} thread(s); load average {load:.2f}")


def bench_tracer(size: int = 128, views: int = 8) -> None:
    K, w2c = lattice_cameras(width=size, height=size)
    rng = np.random.default_rng(0)
    print(f"sphere tracing, {size}x{size}, {views} views per batch:")
    for family in FAMILIES:
        shape = ShapeSDF(sample_shape(family, rng))
        ks = np.linspace(0, 31, views).astype(int)
        d = torch.cat([pixel_rays(K[k], w2c[k], size, size).reshape(-1, 3) for k in ks])
        o = torch.cat([torch.as_tensor(np.linalg.inv(w2c[k])[:3, 3], dtype=torch.float32)
                       .expand(size * size, 3) for k in ks]).contiguous()
        t = time.perf_counter()
        tr = sphere_trace(shape, o, d, step_factor=shape.step_factor)
        dt = time.perf_counter() - t
        print(f"  {family:13s} {len(d) / dt:10.0f} rays/s  {tr.steps / len(d):5.1f} SDF evals/ray"
              f"  hit {float(tr.hit.float().mean()):.2f}")


def bench_generation(preset: str, scenes: int, workers: int | None) -> None:
    data = OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "data" / f"{preset}.yaml"))
    cfg = BenchmarkConfig(**data)
    total = cfg.num_scenes
    if scenes > 0:
        cfg.num_train_scenes, cfg.num_val_scenes, cfg.num_test_scenes = scenes, 0, 0
    if workers is not None:
        cfg.workers = workers
    with tempfile.TemporaryDirectory() as tmp:
        stats = generate_dataset(Path(tmp) / "bench", cfg, seed=0)
    per_scene = [s["seconds"] for s in stats["scenes"]]
    print(f"generation, preset {preset} ({cfg.image_size} px, {cfg.supersample}x{cfg.supersample} "
          f"spp, {cfg.num_scenes} scene(s), {cfg.workers} worker(s)):")
    print(f"  wall {stats['seconds']:.1f} s (environments {stats['env_seconds']:.1f} s); "
          f"per scene {np.mean(per_scene):.1f} s (min {min(per_scene):.1f}, "
          f"max {max(per_scene):.1f}); {stats['rays_per_s']:.0f} rays/s end to end per worker")
    if scenes > 0:
        est = stats["env_seconds"] + np.mean(per_scene) * total / cfg.workers
        print(f"  extrapolated whole preset ({total} scenes): {est / 60:.1f} min")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="small", choices=["tiny", "small", "paper"])
    parser.add_argument("--scenes", type=int, default=2, help="0 = the whole preset")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--skip-tracer", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(machine())
    if not args.skip_tracer:
        bench_tracer()
    bench_generation(args.preset, args.scenes, args.workers)


if __name__ == "__main__":
    main()
