"""Times forward + backward of the pure-torch 2DGS rasterizer.

Scene: 5,000 random surfels (centres uniform in [-1, 1]^3, random rotations,
scales exp(U(-4.5, -3)) ~ 0.011-0.05 world units, opacities U(0.05, 0.95), SH
degree 3, 5 PBR feature channels), one camera at distance 4 with a 40 degree
field of view. Loss = sum of every output map, so every channel is
differentiated.

Timed with 1 and with all torch threads: on a shared machine (other processes
busy) two OpenMP threads stall on every parallel op and one thread is faster.

Run: PYTHONPATH=. python benchmarks/bench_rasterize.py [--sizes 64 128] [--repeats 7] [--threads 1 2]
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import time

import torch

from gspi.gaussians.cameras import intrinsics_from_fov, look_at
from gspi.gaussians.rasterize import rasterize_2dgs


def make_scene(num: int, seed: int = 0) -> dict:
    """Random surfels as leaf tensors that require grad."""
    g = torch.Generator().manual_seed(seed)
    leaves = {
        "means": torch.rand(num, 3, generator=g) * 2 - 1,
        "quats": torch.randn(num, 4, generator=g),
        "scales": torch.exp(torch.rand(num, 2, generator=g) * 1.5 - 4.5),
        "opacities": torch.rand(num, generator=g) * 0.9 + 0.05,
        "colors": torch.randn(num, 16, 3, generator=g) * 0.3,
        "features": torch.rand(num, 5, generator=g),
    }
    return {k: v.requires_grad_() for k, v in leaves.items()}


def time_once(scene: dict, size: int) -> float:
    """Seconds for one forward + backward at ``size`` x ``size`` pixels."""
    eye = torch.tensor([0.0, -1.0, -4.0]) * 4 / math.sqrt(17)  # distance 4 from the origin
    viewmat = look_at(eye, torch.zeros(3), torch.tensor([0.0, -1.0, 0.0]))
    K = intrinsics_from_fov(math.radians(40), size, size)
    start = time.perf_counter()
    out = rasterize_2dgs(
        scene["means"], scene["quats"], scene["scales"], scene["opacities"], scene["colors"],
        viewmat[None], K[None], size, size, features=scene["features"], sh_degree=3, backend="torch",
    )
    loss = out.rgb.sum() + out.features.sum() + out.depth_expected.sum() + out.depth_median.sum() + out.normals.sum()
    loss.backward()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num", type=int, default=5000)
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, torch.get_num_threads()])
    args = parser.parse_args()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average {load:.2f}, torch {torch.__version__}")
    scene = make_scene(args.num)
    for threads in dict.fromkeys(args.threads):
        torch.set_num_threads(threads)
        for size in args.sizes:
            time_once(scene, size)  # warm-up
            times = [time_once(scene, size) for _ in range(args.repeats)]
            print(f"{args.num} surfels, {size}x{size} px, {threads} thread(s), forward+backward: "
                  f"median {statistics.median(times):.3f} s (min {min(times):.3f}, max {max(times):.3f}, "
                  f"{args.repeats} runs)")


if __name__ == "__main__":
    main()
