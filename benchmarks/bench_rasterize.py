"""Times forward + backward of the CPU 2DGS rasterizer: torch reference vs numba compositing.

Scene: N random surfels (centres uniform in [-1, 1]^3, random rotations, scales
exp(U(-4.5, -3)) ~ 0.011-0.05 world units, opacities U(0.05, 0.95), SH degree 3,
5 PBR feature channels), one camera at distance 4 with a 40 degree field of view.
Loss = sum of every output map, so every channel is differentiated. Or ``--asset``: a
shipped demo asset (``checkpoints/demo_assets/<name>/point_cloud.ply``, e.g. the 5,580
surfels of s006 that docs/STAGE3.md times) seen from lattice view 0, random features.

Two timings per (N, size), each forward + backward:

  full       ``rasterize_2dgs`` end to end (projection, SH, binning, compositing);
  composite  the compositing alone on a prepared surfel table and tile lists (the part
             the numba backend replaces): ``torch_backend.composite_tiles`` vs
             ``numba_composite.composite_view``.

Variants: torch (one torch thread), numba with each ``--numba-threads`` count (torch
still one thread: two OpenMP threads stall on a shared machine). The variants run
interleaved, repeat after repeat, so a change of machine load hits them alike;
medians and the ratios of medians are printed. Where one torch run takes longer than
``--torch-limit`` seconds, that single run stands for torch (marked "1 run").

Run: python -m benchmarks.bench_rasterize [--nums 5000] [--sizes 64 128] [--repeats 7]
     python -m benchmarks.bench_rasterize --nums 5000 50000 200000 --sizes 64 128 256 --repeats 5
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

from benchmarks.common import machine
from gspi.gaussians import numba_jit
from gspi.gaussians.cameras import intrinsics_from_fov, look_at
from gspi.gaussians.lattice_render import lattice_camera_tensors
from gspi.gaussians.numba_composite import composite_view
from gspi.gaussians.ply import read_ply
from gspi.gaussians.projection import project_surfels
from gspi.gaussians.rasterize import rasterize_2dgs, view_colors
from gspi.gaussians.tiles import bin_splats, pixel_bounds
from gspi.gaussians.torch_backend import composite_tiles, surfel_table

ASSETS = Path(__file__).resolve().parents[1] / "checkpoints" / "demo_assets"


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


def asset_scene(name: str) -> dict:
    """A demo asset's activated surfels as leaf tensors that require grad (+ random features)."""
    g = read_ply(ASSETS / name / "point_cloud.ply")
    leaves = {"means": g.means, "quats": g.quats, "scales": g.scales, "opacities": g.opacities, "colors": g.sh,
              "features": torch.rand(g.num_gaussians, 5, generator=torch.Generator().manual_seed(0))}
    scene = {k: v.detach().float().clone().requires_grad_() for k, v in leaves.items()}
    scene["lattice"] = True
    return scene


def camera(scene: dict, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """[1, 4, 4] world-to-camera and [1, 3, 3] intrinsics: lattice view 0 for an asset, else
    distance 4 from the origin."""
    if scene.get("lattice"):
        viewmats, Ks = lattice_camera_tensors(size)
        return viewmats[:1], Ks[:1]
    eye = torch.tensor([0.0, -1.0, -4.0]) * 4 / math.sqrt(17)
    viewmat = look_at(eye, torch.zeros(3), torch.tensor([0.0, -1.0, 0.0]))
    return viewmat[None], intrinsics_from_fov(math.radians(40), size, size)[None]


def full_step(scene: dict, size: int, backend: str) -> Callable[[], None]:
    """One ``rasterize_2dgs`` forward + backward."""
    viewmats, Ks = camera(scene, size)

    def step() -> None:
        out = rasterize_2dgs(
            scene["means"], scene["quats"], scene["scales"], scene["opacities"], scene["colors"],
            viewmats, Ks, size, size, features=scene["features"], sh_degree=3, backend=backend,
        )
        loss = (out.rgb.sum() + out.features.sum() + out.depth_expected.sum() + out.depth_median.sum()
                + out.normals.sum())
        loss.backward()

    return step


def composite_step(scene: dict, size: int, backend: str) -> Callable[[], None]:
    """The compositing alone, forward + backward, on a table and tile lists built once."""
    viewmats, Ks = camera(scene, size)
    with torch.no_grad():
        proj = project_surfels(scene["means"], scene["quats"], scene["scales"], viewmats, Ks, size, size,
                               0.01, 1e10)
        rgb = view_colors(scene["colors"], scene["means"], viewmats, 3)[0]
        channels = torch.cat([rgb, scene["features"], proj.normals[0]], -1)
        rt, m2d, depths = proj.ray_transforms[0], proj.means2d[0], proj.depths[0]
        lo, hi, valid = pixel_bounds(rt, m2d, scene["opacities"], size, size)
        bins = bin_splats(lo, hi, valid & (depths > 0.01), depths, size, size, 8)
        table = surfel_table(rt, m2d, depths, scene["opacities"], channels)
    table.requires_grad_()

    def step() -> None:
        if backend == "numba":
            image = composite_view(table, bins, lo, hi, size, size, True)
        else:
            image = composite_tiles(table, bins, size, size, True)
        image.sum().backward()

    return step


def seconds(fn: Callable[[], None]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def compare(make: Callable[[str], Callable[[], None]], numba_threads: list[int], repeats: int,
            torch_limit: float) -> dict[str, list[float]]:
    """Interleaved timings {variant: seconds} of "torch" and "numba <n>t" for each thread count."""
    variants = [("torch", None, make("torch"))] + [(f"numba {n}t", n, make("numba")) for n in numba_threads]
    times: dict[str, list[float]] = {name: [] for name, _, _ in variants}
    once: set[str] = set()  # variants whose warm-up run took over torch_limit: that run stands
    try:
        for name, threads, fn in variants:  # warm-up (numba's compilation is cached on disk)
            numba_jit.set_threads(threads)
            first = seconds(fn)
            if name == "torch" and first > torch_limit:
                times[name], once = [first], {name}
        for _ in range(repeats):
            for name, threads, fn in variants:
                if name in once:
                    continue
                numba_jit.set_threads(threads)
                times[name].append(seconds(fn))
    finally:
        numba_jit.set_threads(None)
    return times


def report(label: str, times: dict[str, list[float]]) -> None:
    med = {name: statistics.median(t) for name, t in times.items()}
    parts = []
    for name, t in times.items():
        runs = "1 run" if len(t) == 1 else f"{len(t)} runs"
        ratio = f", {med['torch'] / med[name]:.1f}x torch" if name != "torch" else ""
        parts.append(f"{name} {1e3 * med[name]:.1f} ms ({runs}{ratio})")
    threads = [name for name in med if name.startswith("numba")]
    if len(threads) > 1:
        parts.append(f"{threads[-1]} / {threads[0]}: {med[threads[0]] / med[threads[-1]]:.2f}x")
    print(f"{label}: " + " | ".join(parts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nums", type=int, nargs="+", default=[5000])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--numba-threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--torch-limit", type=float, default=20.0, help="seconds; above, one torch run only")
    parser.add_argument("--asset", default=None, help=f"a folder of {ASSETS} instead of random surfels")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(machine())
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    scenes = [(args.asset, asset_scene(args.asset))] if args.asset else [(n, make_scene(n)) for n in args.nums]
    for label, scene in scenes:
        num = f"{args.asset} ({len(scene['means'])})" if args.asset else label
        for size in args.sizes:
            for kind, make in (("full", full_step), ("composite", composite_step)):
                times = compare(functools.partial(make, scene, size), args.numba_threads, args.repeats,
                                args.torch_limit)
                report(f"{num} surfels, {size}x{size} px, {kind} fwd+bwd, median", times)
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
