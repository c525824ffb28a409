"""Issue 66, item 2(a): is the capture light told by the views? For each test scene, the pool's
capture environments are the candidates, all turned by one seeded random angle (so the scene's
light is a set member turned by that angle) and the observed radiance scaled by a seeded random
gain; ``gspi.light.estimate.estimate_light`` must name the environment, the turn (within 15
degrees) and the gain. Writes one JSON (per scene: truth, estimate, margin, seconds) and prints
the summary.

    python -m experiments.known_light.identify HELDOUT_TEST VIEWS --out results/identify_exact.json

VIEWS: the folder whose lattice views are read (the exact renders, or a reconstructed pool's).
Normals: GT (``--normals gt``) or the Stage 0 asset's surfel normals (``--normals surfel``).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from eval.common.layout import read_scene, read_splits
from experiments.known_light.fit import POOL_ENVS
from experiments.known_light.scene_fit import asset_normals, env_path, gt_normals, observations, subset
from eval.common.imageio import read_exr
from eval.relight import prefilter_environment
from gspi.light.estimate import MAX_POINTS, estimate_light
from gspi.light.observations import PointViews
from gspi.light.shading import rotate_latlong
from gspi.stage2.data import load_scene_points

GAIN_RANGE = (0.5, 2.0)


def turn_matters(envmap: torch.Tensor) -> bool:
    """Whether turning the map about the up axis changes it (not so for a light with no azimuthal
    structure, e.g. `overcast`: every turn shades alike, so no turn is wrong)."""
    rows = envmap.mean(dim=-1)
    return bool((rows.std(dim=1) / rows.mean(dim=1).clamp_min(1e-12)).max() > 1e-3)


def angle_error(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("views", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", nargs="*", default=None, help="these scenes only (a check; the summary covers them)")
    ap.add_argument("--normals", choices=("gt", "surfel"), default="gt",
                    help="GT normals, or the Stage 0 asset's surfel normals (VIEWS a reconstructed pool)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    names = read_splits(args.data)["test"]
    maps = {e: torch.from_numpy(read_exr(env_path(args.data / names[0], e)).astype(np.float32)) for e in POOL_ENVS}
    rows = []
    for index, name in enumerate(names):
        if args.only and name not in args.only:
            continue
        rng = np.random.default_rng([args.seed, index])
        width = next(iter(maps.values())).shape[1]
        cols = int(rng.integers(width))
        gain = float(np.exp(rng.uniform(*np.log(GAIN_RANGE))))
        t0 = time.perf_counter()
        candidates = {e: prefilter_environment(rotate_latlong(m, cols)) for e, m in maps.items()}
        t_pre = time.perf_counter() - t0
        points = load_scene_points(args.data / name, None)
        keep = subset(points, index, MAX_POINTS, seed=args.seed)
        normals = (gt_normals(args.data / name, points) if args.normals == "gt"
                   else asset_normals(points, keep, args.views / name))
        obs = observations(points, keep, args.views / name, normals)
        obs = PointViews(point=obs.point, colour=obs.colour * gain, view_dir=obs.view_dir, normal=obs.normal,
                         xyz=obs.xyz)
        t1 = time.perf_counter()
        est = estimate_light(obs, candidates, seed=index)
        seconds = time.perf_counter() - t1
        true_rot = (360.0 * cols / width) % 360.0  # a candidate rolled by k columns is turned by -360 k / W
        truth = read_scene(args.data / name).capture_env
        row = {"scene": name, "env": truth, "rotation_deg": true_rot, "gain": gain,
               "estimate": {"env": est.env, "rotation_deg": est.rotation_deg, "gain": est.gain,
                            "score": est.best.score, "margin": est.margin, "turn_margin": est.turn_margin},
               "turn_matters": turn_matters(maps[truth]),
               "env_ok": est.env == truth, "rotation_error_deg": angle_error(est.rotation_deg, true_rot),
               "gain_ratio": est.gain / gain, "seconds": round(seconds, 2), "prefilter_seconds": round(t_pre, 2)}
        rows.append(row)
        print(f"{name}: {truth} {true_rot:.0f} deg x{gain:.2f} -> {est.env} {est.rotation_deg:.1f} deg "
              f"x{est.gain:.2f} (margin {est.margin:.2f}, turn margin {est.turn_margin:.2f}, {seconds:.1f} s)",
              flush=True)
    ok = [r["env_ok"] and (r["rotation_error_deg"] <= 15.0 or not r["turn_matters"]) for r in rows]
    summary = {"scenes": len(rows), "env_identified": sum(r["env_ok"] for r in rows),
               "env_and_rotation_within_15deg": sum(ok),
               "turn_irrelevant": sum(not r["turn_matters"] for r in rows),
               "median_rotation_error_deg": float(np.median([r["rotation_error_deg"] for r in rows])),
               "median_abs_log2_gain_error": float(np.median([abs(math.log2(r["gain_ratio"])) for r in rows])),
               "median_seconds": float(np.median([r["seconds"] for r in rows]))}
    print(json.dumps(summary))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"summary": summary, "views": args.views.name, "normals": args.normals,
                                    "candidates": list(POOL_ENVS), "gain_range": GAIN_RANGE, "scenes": rows},
                                   indent=1) + "\n")


if __name__ == "__main__":
    main()
