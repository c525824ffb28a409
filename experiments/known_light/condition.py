"""What a light-aware Stage II is given: the ``stage2.data.light_readout`` condition's own
read-out (posterior roughness, metallic, albedo; columns 0-4 of the +7), built exactly as Table
2's measure builds it for the model (the light estimated among the candidates, the cloud's PCA
normals, a seeded 5000-point subset and each point's nearest row), scored by Table 2's measure
as if it were the prediction. A learned prior given this condition should score at least this.

    python -m experiments.known_light.condition CHECKPOINT HELDOUT_TEST OUT --baseline SCORES.json \
        [--results experiments/known_light/results/<name> --label NAME] [--asset]

CHECKPOINT: a light-aware model's (only its config is read: ``stage2.data``'s light keys).
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np
import torch

from gspi.stage2.data import PointDataConfig
from gspi.stage2.light_condition import READOUT_PBR_COLUMNS


def condition_prediction(scene, data_cfg: PointDataConfig) -> np.ndarray:
    """[P, 5] (albedo sRGB, roughness, metallic) of every point: the condition's read-out columns."""
    rows = scene.light_features(np.arange(scene.num_points), data_cfg)
    return np.ascontiguousarray(rows[:, list(READOUT_PBR_COLUMNS)].clip(0.0, 1.0))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint", type=Path)
    ap.add_argument("data", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--baseline", type=Path, required=True, help="a scores.json whose baseline constants to reuse")
    ap.add_argument("--results", type=Path, default=None, help="also write the scores here with portable paths")
    ap.add_argument("--label", default=None)
    ap.add_argument("--asset", action="store_true",
                    help="read as a run reads it: stage2.data.light_geometry=asset, normals searched at 4 and 8 degrees")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    from gspi.stage2.checkpoint import load_stage2_checkpoint
    from gspi.stage2.evaluate_points import score_split

    _, cfg = load_stage2_checkpoint(args.checkpoint)
    data_cfg: PointDataConfig = cfg["stage2"].data
    if args.asset:
        from dataclasses import replace

        data_cfg = replace(data_cfg, light_geometry="asset", light_normal_search_deg=(4.0, 8.0))
    lights: dict[str, dict] = {}

    def predict(scene, index):
        pred = condition_prediction(scene, data_cfg)
        lights[scene.name] = scene.light_info
        return pred

    record = {"ablation": "light_readout_condition", "checkpoint": None, "num_steps": None, "max_points": None,
              "seed": 0, "light_condition": {"source": "estimated", "of_checkpoint": args.checkpoint.name,
                                             "geometry": data_cfg.light_geometry,
                                             "normal_search_deg": data_cfg.light_normal_search_deg}}
    result = score_split(predict, cfg, args.data, "test", args.out, baseline_train=args.baseline, record=record)
    (args.out / "lights.json").write_text(json.dumps(lights, indent=1, default=float))
    print(json.dumps({c: round(v["psnr"], 2) for c, v in result["mean"]["stage2"].items()}))
    if args.results:
        from eval.portable import write_portable_scores

        write_portable_scores(args.out / "scores.json", args.results / "scores.json",
                              data_label=args.label or args.data.name, roots={"<work>": args.data.resolve().parent})
        (args.results / "lights.json").write_text(json.dumps(lights, indent=1, default=float))


if __name__ == "__main__":
    main()
