"""The read-out's two settings (posterior temperature, neighbours pooled) chosen on training-pool
scenes (never the held-out ones): per-point PSNR of albedo, roughness and metallic against the GT
points, averaged over scenes, for each setting; prints a markdown table.

    python -m experiments.known_light.tune POOL_DIR [--out experiments/known_light/results/tune.json]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from eval.common.colorspace import linear_to_srgb
from experiments.known_light.scene_fit import env_path, gt_normals, observations, prefiltered, subset
from gspi.light.readout import fit_grid, pool_neighbours, read_best, read_posterior
from gspi.stage2.data import load_scene_points
from gspi.stage2.normalize import pbr_from_model

TEMPERATURES = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
NEIGHBOURS = (8, 16, 32)


def psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    return float(-10 * np.log10(max(np.mean((pred - gt) ** 2), 1e-6)))


def scores(albedo, rough, metal, gt) -> dict[str, float]:
    a = linear_to_srgb(albedo).numpy()
    return {"albedo": psnr(a, gt[:, :3]), "roughness": psnr(rough.numpy(), gt[:, 3]),
            "metallic": psnr(metal.numpy(), gt[:, 4])}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pool", type=Path)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    rows: dict[str, list[dict]] = {}
    scenes = sorted(p for p in args.pool.iterdir() if (p / "gt_points.npz").is_file())
    for index, scene_dir in enumerate(scenes):
        points = load_scene_points(scene_dir, None)
        keep = subset(points, index, 5000)
        obs = observations(points, keep, scene_dir, gt_normals(scene_dir, points))
        grid = fit_grid(obs, prefiltered(str(env_path(scene_dir, None))))
        gt = pbr_from_model(torch.from_numpy(points.f0[keep])).numpy()
        rows.setdefault("map", []).append(scores(*read_best(grid), gt))
        for k in NEIGHBOURS:
            pooled = pool_neighbours(grid, obs.xyz, k=k)
            for t in TEMPERATURES:
                rows.setdefault(f"k={k} T={t}", []).append(scores(*read_posterior(grid, pooled, t), gt))
        print(f"{scene_dir.name} done", flush=True)
    table = {name: {c: float(np.mean([r[c] for r in rs])) for c in rs[0]} for name, rs in rows.items()}
    print("| read-out | albedo | roughness | metallic | mean |\n|---|---|---|---|---|")
    for name, s in table.items():
        print(f"| {name} | {s['albedo']:.2f} | {s['roughness']:.2f} | {s['metallic']:.2f} | {np.mean(list(s.values())):.2f} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"scenes": [s.name for s in scenes], "per_point_psnr": table}, indent=1) + "\n")


if __name__ == "__main__":
    main()
