"""Times Stage III distillation: seconds per iteration and where they go.

Asset: a shipped demo 2DGS asset (``checkpoints/demo_assets/<scene>/point_cloud.ply``, the
``recon=fast`` reconstruction of a ``small`` test scene, ~5k surfels). Targets: the asset's own
rendered SH base colour as albedo, roughness 0.5, metallic 0.1, valid where the asset's alpha is
>= 0.5, in the 32 lattice views at each ``--sizes`` (so the numbers do not depend on a Stage II
model). Reports, per size, the medians over ``--repeats`` single-view iterations of

  render   forward rasterization of the material maps (``render_materials``)
  loss     the masked L1 + D-SSIM objective (``masked_material_loss``)
  backward autograd through both
  step     Adam + lr schedule

for the default config (PBR logits, opacities and scales trained) and for A9 (geometry frozen),
then ``distill()`` end to end for ``--iterations`` iterations (iterations/s; the init included
separately).

    python -m benchmarks.bench_stage3                  # 64 and 128 px, one thread
    python -m benchmarks.bench_stage3 --sizes 512      # paper resolution (GPU advised)
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import machine
from eval.common.colorspace import linear_to_srgb
from gspi.gaussians.ply import read_ply
from gspi.gaussians.lattice_render import lattice_camera_tensors
from gspi.stage3.config import Stage3Config
from gspi.stage3.distill import distill, trainable_groups
from gspi.stage3.init import initialize_pbr
from gspi.stage3.loss import PROPERTIES, masked_material_loss
from gspi.stage3.render import render_base_color, render_geometry, render_materials
from gspi.stage3.targets import StagedTargets

ASSETS = Path(__file__).resolve().parents[1] / "checkpoints" / "demo_assets"
PHASES = ("render", "loss", "backward", "step")


def self_targets(asset, size: int, num_views: int = 32) -> StagedTargets:
    """Targets rendered from the asset itself (see the module doc)."""
    w2c, K = lattice_camera_tensors(size)
    w2c, K = w2c[:num_views], K[:num_views]
    alpha, _ = render_geometry(asset, w2c, K, size, size)
    albedo = linear_to_srgb(render_base_color(asset, w2c, K, size, size)).numpy().astype(np.float32)
    shape = albedo.shape[:3] + (1,)
    return StagedTargets(albedo=albedo, roughness=np.full(shape, 0.5, np.float32),
                         metallic=np.full(shape, 0.1, np.float32), valid=(alpha >= 0.5).numpy(),
                         K=K.numpy(), w2c=w2c.numpy())


def phase_times(asset, targets: StagedTargets, cfg: Stage3Config, repeats: int) -> dict[str, float]:
    """Median seconds of each phase of one single-view distillation iteration."""
    t = targets.tensors()
    alpha, depth = render_geometry(asset, t["w2c"], t["K"], targets.width, targets.height, backend=cfg.backend)
    out, _ = initialize_pbr(asset, targets, cfg, depth=depth)
    mask = (alpha >= cfg.loss.silhouette_threshold) & t["valid"]
    optimizer = torch.optim.Adam(trainable_groups(out, cfg), eps=1e-15)
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimizer, 0.999)
    times: dict[str, list[float]] = {p: [] for p in PHASES}
    for it in range(repeats + 1):  # the first is a warm-up
        idx = torch.tensor([it % targets.num_views])
        marks = [time.perf_counter()]
        pred = render_materials(out, t["w2c"][idx], t["K"][idx], targets.width, targets.height, backend=cfg.backend)
        marks.append(time.perf_counter())
        loss, _ = masked_material_loss(pred, {p: t[p][idx] for p in PROPERTIES}, mask[idx],
                                       weights=cfg.weights, ssim_lambda=cfg.loss.ssim_lambda)
        marks.append(time.perf_counter())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        marks.append(time.perf_counter())
        optimizer.step()
        scheduler.step()
        marks.append(time.perf_counter())
        if it:
            for name, a, b in zip(PHASES, marks, marks[1:]):
                times[name].append(b - a)
    return {name: statistics.median(v) for name, v in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="s006_blob_glossy_plastic", help=f"a folder of {ASSETS}")
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--repeats", type=int, default=15, help="iterations timed per phase breakdown")
    parser.add_argument("--iterations", type=int, default=40, help="distill() iterations timed end to end")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--backend", default="auto")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    ply = ASSETS / args.scene / "point_cloud.ply"
    asset = read_ply(ply)
    print(f"machine: {machine()}")
    print(f"asset: {ply.relative_to(ASSETS.parents[1])}, {asset.num_gaussians} surfels; backend {args.backend}")
    for size in args.sizes:
        targets = self_targets(asset, size)
        print(f"\n{size}x{size} px, 32 lattice views, 1 view per iteration")
        print(f"  {'config':<28} " + " ".join(f"{p:>9}" for p in PHASES) + f" {'total':>9}   (median ms)")
        for label, freeze in (("default (opacity+scales)", False), ("A9 (geometry frozen)", True)):
            cfg = Stage3Config(backend=args.backend, freeze_opacity=freeze, freeze_scales=freeze)
            phases = phase_times(asset, targets, cfg, args.repeats)
            print(f"  {label:<28} " + " ".join(f"{1e3 * phases[p]:9.1f}" for p in PHASES)
                  + f" {1e3 * sum(phases.values()):9.1f}")
        cfg = Stage3Config(backend=args.backend, iterations=args.iterations, log_every=10 ** 9)
        _, stats = distill(asset, targets, cfg)
        print(f"  distill(), default config: {1 / stats['seconds_per_iteration']:.2f} it/s over "
              f"{args.iterations} iterations (init {stats['seconds_init']:.2f} s); 500 iterations ~ "
              f"{500 * stats['seconds_per_iteration'] + stats['seconds_init']:.0f} s")


if __name__ == "__main__":
    main()
