"""Roughness and metal on controlled pairs (issue 52, item 4): does a run read what the photos show?

The dataset (`gspi-data preset=controlled_pairs`, gspi/data/controlled_pairs.py) holds pairs of
scenes that differ ONLY in roughness (a glossy and a matte dielectric) or ONLY in metal vs
dielectric (same base colour). For each scene this script takes the run's predicted roughness and
metallic, averaged over the ground-truth mask of every scored view (all pixels of the split's
views pooled), and reports per pair and in all:

- glossy/matte pairs: the fraction **ordered** (glossy mean < matte mean) and the fraction ordered
  with a predicted gap >= `--min-gap` (0.3, issue 52's target: >= 90 % of pairs);
- metal/dielectric pairs: the fraction **separated** at `--threshold` (metal mean > 0.5 and
  dielectric mean < 0.5; target >= 90 %).

End to end, at the `small` size with today's Stage 0 (`recon=fast`) and the shipped Stage II:

    gspi-data preset=controlled_pairs out=data/pairs seed=0              # 18 pairs (add
                                                  # data.controlled_pairs.colours=1 for 6 pairs)
    gspi-run data=data/pairs out=runs/pairs recon=fast logger=none
    python benchmarks/bench_controlled_pairs.py runs/pairs --data data/pairs \\
        --json results/controlled_pairs/cpu/gspi_recon_fast.json

`RUN` is a gspi-run job folder (its predictions/<scene>/<split>/<view>/roughness.png and
metallic.png, docs/FORMAT.md); a scene of the manifest without predictions is an error naming it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

from eval.common.atomic import write_json_atomic
from eval.common.layout import read_scene, read_view_file
from gspi.data.controlled_pairs import KIND_MEMBERS, read_manifest
from gspi.publish.pairs import pairs_table

CHANNELS = ("roughness", "metallic")
MIN_GAP = 0.3      # issue 52: a glossy/matte pair counts as read when ordered by at least this much
THRESHOLD = 0.5    # issue 52: metal above, dielectric below


def masked_means(data_scene: Path, pred_scene: Path, split: str = "test") -> dict[str, float]:
    """Predicted roughness and metallic averaged over the GT foreground of every `split` view.

    Args:
        data_scene: the ground-truth scene folder (its scene.json names the views; mask.png).
        pred_scene: the prediction folder of the same scene (<split>/<view>/<channel>.png).
    Returns:
        {"roughness": mean, "metallic": mean}, over all masked pixels of the views pooled.
    Raises:
        ValueError: a prediction file is missing, or the views hold no foreground pixel.
    """
    scene = read_scene(data_scene)
    sums, count = dict.fromkeys(CHANNELS, 0.0), 0
    for view in scene.split_views(split):
        mask = read_view_file(scene.view_dir(split, view.id), "mask.png")[..., 0] > 0.5
        for channel in CHANNELS:
            path = pred_scene / split / view.id / f"{channel}.png"
            if not path.is_file():
                raise ValueError(f"{path}: missing (the run predicted no {channel} for scene {scene.name})")
            sums[channel] += float(read_view_file(path.parent, path.name)[..., 0][mask].astype(np.float64).sum())
        count += int(mask.sum())
    if count == 0:
        raise ValueError(f"{data_scene}: no foreground pixel in the {split} views")
    return {channel: sums[channel] / count for channel in CHANNELS}


def score_pairs(pairs: list[dict], means: dict[str, dict[str, float]], *, min_gap: float = MIN_GAP,
                threshold: float = THRESHOLD) -> dict:
    """Per-pair verdicts and the fractions (module docstring); a pure function of the means.

    Args:
        pairs: manifest entries (gspi.data.controlled_pairs.read_manifest).
        means: scene name -> {"roughness": mean, "metallic": mean} (masked_means).
    Returns:
        {"pairs": [row per pair], "roughness": {"pairs", "ordered", "ordered_with_gap"},
         "metal": {"pairs", "separated"}, "min_gap", "threshold"}; fractions in [0, 1], None for
         a kind without pairs.
    """
    rows = []
    for pair in pairs:
        low, high = KIND_MEMBERS[pair["kind"]]
        m = {member: means[pair["scenes"][member]] for member in (low, high)}
        row = {"id": pair["id"], "kind": pair["kind"], "family": pair["family"], "scenes": pair["scenes"],
               **{c: {member: m[member][c] for member in (low, high)} for c in CHANNELS}}
        if pair["kind"] == "roughness":
            gap = m[high]["roughness"] - m[low]["roughness"]
            row |= {"gap": gap, "ordered": bool(gap > 0), "ordered_with_gap": bool(gap >= min_gap)}
        else:
            row["separated"] = bool(m[high]["metallic"] > threshold and m[low]["metallic"] < threshold)
        rows.append(row)

    def fraction(kind: str, key: str):
        hits = [r[key] for r in rows if r["kind"] == kind]
        return sum(hits) / len(hits) if hits else None
    return {"pairs": rows, "min_gap": min_gap, "threshold": threshold,
            "roughness": {"pairs": sum(r["kind"] == "roughness" for r in rows),
                          "ordered": fraction("roughness", "ordered"),
                          "ordered_with_gap": fraction("roughness", "ordered_with_gap")},
            "metal": {"pairs": sum(r["kind"] == "metal" for r in rows),
                      "separated": fraction("metal", "separated")}}


def score_run(run: Path, data: Path, manifest: Path | None = None, *, split: str = "test",
              min_gap: float = MIN_GAP, threshold: float = THRESHOLD, pair_ids: list[str] | None = None) -> dict:
    """`score_pairs` of a gspi-run folder's predictions on a controlled-pairs dataset (only the
    pairs `pair_ids` when given, e.g. of a run made with `scenes=[...]`)."""
    pairs = read_manifest(manifest or data)
    if pair_ids is not None:
        unknown = sorted(set(pair_ids) - {p["id"] for p in pairs})
        if unknown:
            raise ValueError(f"{manifest or data}: no pairs {unknown} (has {[p['id'] for p in pairs]})")
        pairs = [p for p in pairs if p["id"] in pair_ids]
    scenes = sorted({s for p in pairs for s in p["scenes"].values()})
    means = {s: masked_means(data / s, run / "predictions" / s, split) for s in scenes}
    return {"run": str(run), "data": str(data), "split": split, "overrides": hydra_overrides(run),
            "data_overrides": hydra_overrides(data),
            **score_pairs(pairs, means, min_gap=min_gap, threshold=threshold)}


def hydra_overrides(folder: Path) -> list[str] | None:
    """The command-line overrides that made a gspi-run or gspi-data folder (its .hydra/overrides.yaml),
    None without one."""
    path = folder / ".hydra" / "overrides.yaml"
    return [str(o) for o in yaml.safe_load(path.read_text()) or []] if path.is_file() else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a gspi-run job folder (holds predictions/)")
    parser.add_argument("--data", type=Path, required=True, help="the controlled-pairs dataset the run predicted")
    parser.add_argument("--manifest", type=Path, default=None, help="pairs.json (default: DATA/pairs.json)")
    parser.add_argument("--split", default="test", help="the views scored (the protocol's eval.split)")
    parser.add_argument("--min-gap", type=float, default=MIN_GAP)
    parser.add_argument("--threshold", type=float, default=THRESHOLD)
    parser.add_argument("--pairs", default=None, help="comma-separated pair ids to score (default: all)")
    parser.add_argument("--json", type=Path, default=None, help="write the scores there")
    args = parser.parse_args(argv)
    try:
        scores = score_run(args.run, args.data, args.manifest, split=args.split, min_gap=args.min_gap,
                           threshold=args.threshold, pair_ids=args.pairs.split(",") if args.pairs else None)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(pairs_table(scores))
    if args.json is not None:
        write_json_atomic(args.json, scores)
    return 0


if __name__ == "__main__":
    sys.exit(main())
