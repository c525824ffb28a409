"""How far the light read's normals are from the truth behind Stage 0, on the held-out spheres
(their analytic normals): the 256-neighbour PCA normals of Stage I's cloud (``cloud_normals``,
what ``method=light_fit`` and a light-aware Stage II read), for each reconstructed pool given.

    python -m experiments.known_light.normals HELDOUT_TEST OUT.json NAME=RHELDOUT [NAME=RHELDOUT ...]

Per scene and pool: median and 90th percentile angle (degrees) over the cloud's points, and the
cloud's radial spread (std of |x - c| / radius: how bumpy the asset's depth is).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def sphere_center(xyz: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares sphere through ``xyz`` [n, 3]: |x|^2 = 2 c.x + (r^2 - |c|^2), linear in (c, d)."""
    a = np.c_[2 * xyz, np.ones(len(xyz))]
    sol, *_ = np.linalg.lstsq(a, (xyz ** 2).sum(1), rcond=None)
    c = sol[:3]
    return c, float(np.sqrt(sol[3] + c @ c))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("pools", nargs="+", help="NAME=RHELDOUT (a reconstructed pool)")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    from eval.common.layout import read_scene
    from gspi.gaussians.ply import read_ply
    from gspi.stage1.config import Stage1Config
    from gspi.stage1.extract import extract_point_cloud
    from gspi.stage2.lattice_cameras import LatticeCameras
    from gspi.stage2.light_condition import cloud_normals

    out = {}
    for scene_dir in sorted(p for p in args.data.iterdir() if "_sphere_" in p.name):
        gt = np.load(scene_dir / "gt_points.npz")["xyz"].astype(np.float64)
        center, radius = sphere_center(gt)
        size = read_scene(scene_dir).width
        for spec in args.pools:
            name, _, pool = spec.partition("=")
            ply = Path(pool) / scene_dir.name / "asset" / "point_cloud.ply"
            points, renders, _ = extract_point_cloud(read_ply(ply), Stage1Config(image_size=size))
            xyz = points.xyz.astype(np.float64)
            cams = LatticeCameras.from_renders(renders)
            normal = cloud_normals(xyz, xyz, cams.centers[points.view])
            truth = (xyz - center) / np.linalg.norm(xyz - center, axis=1, keepdims=True)
            angle = np.degrees(np.arccos(np.clip(np.abs((normal * truth).sum(1)), -1, 1)))
            spread = float(np.std(np.linalg.norm(xyz - center, axis=1)) / radius)
            out.setdefault(scene_dir.name, {})[name] = {
                "median_deg": round(float(np.median(angle)), 2), "p90_deg": round(float(np.percentile(angle, 90)), 2),
                "radial_spread": round(spread, 4), "points": len(xyz)}
            print(scene_dir.name, name, out[scene_dir.name][name], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
