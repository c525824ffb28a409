"""Issue 66, item 1: the training-free per-point fit with the capture light known, on a Stage II
dataset's test scenes, scored by Table 2's measure (``gspi.stage2.evaluate_points.score_split``):
one ``scores.json`` per read-out (``map``: the best cell; ``knn_post``: the posterior mean of the
grid pooled over 16 neighbours), beside the no-decomposition baseline of the same measure.

    python -m experiments.known_light.fit HELDOUT_TEST VIEWS OUT --baseline SCORES.json \
        [--light true|rotated90|other] [--results experiments/known_light/results/<cond> --label NAME]

HELDOUT_TEST: the GT scenes (points, normals, environments); VIEWS: the folder whose lattice views
are read (the same folder for the exact renders, or a reconstructed pool's); ``--light``: the
scene's capture environment, the same turned 90 degrees, or the next pool environment in name order.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

from eval.common.layout import read_scene
from gspi.stage2.encoders import PriorConfig
from experiments.known_light.scene_fit import READOUTS, Light, predict

POOL_ENVS = ("overcast", "sky_morning", "sky_noon", "studio_rgb", "studio_softbox", "sunset", "warehouse",
             "window_room")  # the procedural capture set the pool cycles over (gspi.data.environments)


def measure_config(data_dir: Path) -> dict:
    """What score_split reads of a Stage II config: no prior (the fit reads no image feature)."""
    return {"stage2": SimpleNamespace(prior=PriorConfig(encoder="none"), data=SimpleNamespace(needs_feature_maps=False)),
            "data_dir": str(data_dir), "seed": 0}


def told_light(scene_dir: Path, mode: str) -> Light:
    if mode == "true":
        return Light()
    if mode == "rotated90":
        return Light(rotation_deg=90.0)
    if mode == "other":
        own = read_scene(scene_dir).capture_env
        return Light(env=POOL_ENVS[(POOL_ENVS.index(own) + 1) % len(POOL_ENVS)])
    raise ValueError(f"--light {mode!r}: expected true, rotated90 or other")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("views", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--baseline", type=Path, required=True, help="a scores.json whose baseline constants to reuse")
    ap.add_argument("--light", default="true")
    ap.add_argument("--temperature", type=float, default=None)
    ap.add_argument("--normals", choices=("gt", "surfel"), default="gt",
                    help="GT normals, or the Stage 0 asset's surfel normals (VIEWS a reconstructed pool)")
    ap.add_argument("--results", type=Path, default=None,
                    help="also write each read-out's scores here with portable paths (the committed copy)")
    ap.add_argument("--label", default=None, help="the measured data's name in the committed copy")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    from gspi.stage2.evaluate_points import score_split

    cache: dict[str, dict[str, np.ndarray]] = {}

    def prediction(readout: str):
        def run(scene, index):
            if scene.name not in cache:
                light = told_light(args.data / scene.name, args.light)
                cache[scene.name] = predict(scene, index, args.data / scene.name, args.views / scene.name, light,
                                            temperature=args.temperature, normals=args.normals)
            return cache[scene.name][readout]
        return run

    cfg = measure_config(args.views)
    for readout in READOUTS:
        record = {"ablation": f"light_fit_{readout}", "checkpoint": None, "num_steps": None,
                  "max_points": 20000, "seed": 0,
                  "light_fit": {"readout": readout, "light": args.light, "normals": args.normals,
                                "views": args.views.name, "temperature": args.temperature}}
        result = score_split(prediction(readout), cfg, args.views, "test", args.out / readout,
                             baseline_train=args.baseline, record=record)
        print(readout, json.dumps({c: round(v["psnr"], 2) for c, v in result["mean"]["stage2"].items()}))
        if args.results:
            from eval.portable import write_portable_scores

            root = Path(__file__).resolve().parents[2]
            write_portable_scores(args.out / readout / "scores.json", args.results / readout / "scores.json",
                                  data_label=args.label or args.views.name,
                                  roots={"<work>": args.data.resolve().parent, "<repo>": root})


if __name__ == "__main__":
    main()
