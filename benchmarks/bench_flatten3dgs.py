"""What flattening a 3DGS asset into 2DGS surfels loses (docs/DATA.md "3DGS input").

A shipped demo asset's surfels are thickened along their normal to ``--thickness`` times their
minor axis (``gspi.gaussians.splat3d.thicken_surfels``) and rendered as 3D splats by the dense
EWA reference (``gspi.gaussians.splat3d_render.render_3dgs``); the surfels themselves are
rendered by gspi's 2DGS rasterizer (what Stages I-III see after ``flatten_3dgs``). PSNR of RGB
(SH colour per view, black background) and of alpha over the lattice views.

    python -m benchmarks.bench_flatten3dgs s006_blob_glossy_plastic --size 64 --views 8
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import machine
from eval.metrics import psnr_from_mse
from gspi.gaussians.cameras import camera_centers
from gspi.gaussians.lattice_render import lattice_camera_tensors, render_lattice_views
from gspi.gaussians.ply import read_ply
from gspi.gaussians.splat3d import thicken_surfels
from gspi.gaussians.splat3d_render import render_3dgs

ASSETS = Path(__file__).resolve().parents[1] / "checkpoints" / "demo_assets"


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return psnr_from_mse(float(((a - b) ** 2).mean()), mse_floor=1e-20)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", nargs="?", default="s006_blob_glossy_plastic", help="a folder of checkpoints/demo_assets")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--thickness", type=float, nargs="*", default=[1e-4, 0.1, 0.3, 1.0])
    args = ap.parse_args()
    torch.set_num_threads(1)
    print(machine())
    surfels = read_ply(ASSETS / args.asset / "point_cloud.ply")
    lattice = {"num_views": args.views}
    flat = render_lattice_views(surfels, image_size=args.size, lattice=lattice)
    viewmats, Ks = lattice_camera_tensors(args.size, lattice=lattice, dtype=torch.float32)
    colors = torch.stack([surfels.colors(c) for c in camera_centers(viewmats)])
    quats, log_scales = thicken_surfels(surfels, 0.0, normal_axis=2)
    for rel in args.thickness:
        log_scales = log_scales.clone()
        log_scales[:, 2] = surfels.log_scales.min(1).values + float(np.log(rel))
        t0 = time.perf_counter()
        rgb, alpha = render_3dgs(surfels.means, quats, log_scales.exp(), surfels.opacities, colors, viewmats, Ks,
                                 args.size, args.size)
        print(f"{args.asset} ({surfels.num_gaussians} surfels), {args.size} px, {args.views} views, thickness "
              f"{rel:g} x minor axis: RGB {psnr(rgb, flat.rgb.clamp_min(0)):.2f} dB, alpha "
              f"{psnr(alpha, flat.alpha):.2f} dB ({time.perf_counter() - t0:.1f} s)")


if __name__ == "__main__":
    main()
