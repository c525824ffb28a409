"""Does the light estimate need its coarse search on all 2 000 identify points? ``method=light_fit``'s
path on each held-out scene behind its ``recon=fast`` asset (Stage I's cloud, the photos, the
cloud's normals: ``observe_cloud``), the light estimated with the coarse search (every candidate
and turn, two thirds of the cost) on ``--coarse`` of the points and the refinement on all of them,
against the light the default estimate (coarse and refine on 2 000) found for the same points,
recorded by ``stage1_read.py`` (``--reference``). ``--time-full N``: on the first N scenes also
run the default estimate here, to time both on the same load.

    python -m experiments.known_light.identify_budget HELDOUT_TEST RHELDOUT OUT.json \
        --reference results/stage1_read_normal_search.json --coarse 600 [--time-full 3]
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import torch

log = logging.getLogger(__name__)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("assets", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--reference", type=Path, required=True, help="a stage1_read.py result (its lights)")
    ap.add_argument("--read", default="photos_normal_search", help="which of its reads' light to compare with")
    ap.add_argument("--coarse", type=int, default=600)
    ap.add_argument("--time-full", type=int, default=0)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    from eval.common.layout import read_scene
    from gspi.light.estimate import estimate_light
    from gspi.stage2.light_condition import candidate_lights
    from gspi.stage2.light_fit import LightFitConfig, observe_cloud
    from experiments.known_light.stage1_read import asset_stage1

    cfg = LightFitConfig()
    candidates = candidate_lights(cfg.candidates, cfg.env_height)
    reference = json.loads(args.reference.read_text())["scenes"]
    done = json.loads(args.out.read_text()) if args.out.is_file() else {"scenes": {}}
    done.update(coarse_points=args.coarse, identify_points=cfg.identify_points, reference=args.reference.name)
    for k, name in enumerate(sorted(reference)):
        if name in done["scenes"]:
            continue
        scene_dir = args.data / name
        points, renders, photos, _ = asset_stage1(scene_dir, args.assets / name / "asset" / "point_cloud.ply")
        obs, _ = observe_cloud(points, renders, cfg, photos)
        t0 = time.perf_counter()
        est = estimate_light(obs, candidates, max_points=cfg.identify_points, coarse_points=args.coarse, seed=cfg.seed)
        row = {"capture_env": read_scene(scene_dir).capture_env, "seconds": round(time.perf_counter() - t0, 2),
               "light": {"env": est.env, "rotation_deg": round(est.rotation_deg, 2), "gain": round(est.gain, 4),
                         "margin": round(est.margin, 3)},
               "reference": reference[name][args.read]["light"]}
        if k < args.time_full:
            t0 = time.perf_counter()
            full = estimate_light(obs, candidates, max_points=cfg.identify_points, seed=cfg.seed)
            row["full"] = {"seconds": round(time.perf_counter() - t0, 2), "env": full.env,
                           "rotation_deg": round(full.rotation_deg, 2)}
        done["scenes"][name] = row
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(done, indent=1))
        log.info("%s: %s", name, row)
    args.out.write_text(json.dumps(done, indent=1))


if __name__ == "__main__":
    main()
