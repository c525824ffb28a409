"""Issue 42's held-out table: Stage II models on the multi-part pool's held-out scenes.

Reads ``scores.json`` folders of ``gspi.stage2.evaluate_points`` (one per model and seed; or the
copies run.sh commits as ``results/heldout/cpu/<run>/scores.json``, which outlive the run folders), groups
the scenes by what the pool made of them (``scene.json``: multi-part or one class; the metal
class by name) and prints, per model, the mean over seeds of the per-seed scene means, the seed
spread, metal-class metallic and metal IoU, multi-part roughness, and the paired differences to
no decomposition (and to ``--reference``) over (scene, seed) with 95 % bootstrap CIs
(``eval.stats.paired_bootstrap_ci``).

    python experiments/training_pools/summary.py --pool RPOOL64 \\
        parts=runs/cpu_parts_pool_s0/eval parts=runs/cpu_parts_pool_s1/eval \\
        pool_recon=runs/ref/pool_recon/eval small=runs/ref/small/eval [--reference pool_recon]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from eval.records.points_scores import BASELINE_KEY
from eval.stats import paired_bootstrap_ci

CHANNELS = ("albedo", "roughness", "metallic")
BASELINE = "no decomposition"


def scene_groups(pool: Path, scenes: list[str]) -> dict[str, set[str]]:
    """{"multi-part": ..., "one class": ..., "metal class": ..., "with metal": ...} by scene.json."""
    groups: dict[str, set[str]] = {"multi-part": set(), "one class": set(), "metal class": set(),
                                   "with metal": set()}
    for name in scenes:
        material = json.loads((pool / name / "scene.json").read_text())["generator"]["material"]
        parts = material.get("parts", {}).get("materials", [material])
        groups["multi-part" if "parts" in material else "one class"].add(name)
        if material["class"] == "metal":
            groups["metal class"].add(name)
        if any(p["class"] in ("metal", "painted_metal") for p in parts):
            groups["with metal"].add(name)
    return groups


def units(source: Path, key: str = "stage2") -> tuple[dict, dict, int]:
    """({(scene, seed): {channel: psnr, "avg": ...}}, {scene: metal IoU}, seed) of one scores folder,
    or of a ``scores.json`` kept under results/heldout/cpu/<run>/ (run.sh copies each run's there)."""
    data = json.loads((source if source.suffix == ".json" else source / "scores.json").read_text())
    seed = data.get("train_seed")
    out = {}
    for scene, ch in data["per_scene"][key].items():
        row = {c: float(ch[c]["psnr"]) for c in CHANNELS}
        row["avg"] = float(np.mean([row[c] for c in CHANNELS]))
        out[(scene, seed)] = row
    return out, data.get("metal_iou", {}).get(key, {}), seed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+",
                        help="NAME=SCORES_FOLDER or NAME=SCORES.json (repeat a name for its seeds)")
    parser.add_argument("--pool", type=Path, required=True, help="the scored dataset (scene.json per scene)")
    parser.add_argument("--reference", default=None, help="also: paired difference to this model (avg)")
    args = parser.parse_args(argv)
    models: dict[str, dict] = {}
    ious: dict[str, dict] = {}
    base: dict = {}
    for spec in args.models:
        name, _, folder = spec.partition("=")
        rows, iou, seed = units(Path(folder))
        models.setdefault(name, {}).update(rows)
        ious.setdefault(name, {}).update({(s, seed): v for s, v in iou.items()})
        b_rows, b_iou, _ = units(Path(folder), BASELINE_KEY)
        base.update({s: r for (s, _), r in b_rows.items()})
        ious.setdefault(BASELINE, {}).update({(s, None): v for s, v in b_iou.items()})
    scenes = sorted(base)
    groups = scene_groups(args.pool, scenes)
    print(f"{len(scenes)} held-out scenes: {len(groups['multi-part'])} multi-part, "
          f"{len(groups['one class'])} one class, {len(groups['metal class'])} metal class, "
          f"{len(groups['with metal'])} with a metal part\n")
    cols = ["albedo", "roughness", "metallic", "avg", "spread", "metal class: metallic", "metal class: IoU",
            "multi-part: roughness", "multi-part: avg"]
    print("| model | seeds | " + " | ".join(cols) + " |")
    print("|---" * (len(cols) + 2) + "|")
    table = {BASELINE: {(s, None): r for s, r in base.items()}, **models}
    for name, rows in table.items():
        seeds = sorted({sd for _, sd in rows}, key=str)

        def mean_of(channel, subset=None):
            per_seed = [np.mean([rows[(s, sd)][channel] for s in scenes if (s, sd) in rows
                                 and (subset is None or s in subset)]) for sd in seeds]
            return float(np.mean(per_seed))
        avgs = [np.mean([rows[(s, sd)]["avg"] for s in scenes if (s, sd) in rows]) for sd in seeds]
        metal = groups["metal class"]
        iou = [ious.get(name, {}).get((s, sd)) for s in metal for sd in seeds]
        cells = [mean_of(c) for c in ("albedo", "roughness", "metallic", "avg")]
        cells += [float(max(avgs) - min(avgs)), mean_of("metallic", metal) if metal else np.nan,
                  float(np.mean([0.0 if v is None else v for v in iou])) if metal else np.nan,
                  mean_of("roughness", groups["multi-part"]), mean_of("avg", groups["multi-part"])]
        print(f"| {name} | {len(seeds)} | " + " | ".join(f"{v:.2f}" for v in cells) + " |")
    print("\nPaired over (scene, seed), 95 % bootstrap CI, model - no decomposition:\n")
    print("| model | scenes | " + " | ".join(CHANNELS) + " | avg |")
    print("|---" * 6 + "|")
    for name, rows in models.items():
        for label, subset in (("all", None), ("multi-part", groups["multi-part"]), ("metal class", groups["metal class"])):
            cells = []
            for c in (*CHANNELS, "avg"):
                variant = {u: r[c] for u, r in rows.items() if subset is None or u[0] in subset}
                reference = {u: base[u[0]][c] for u in variant}
                m, lo, hi = paired_bootstrap_ci(variant, reference)
                cells.append(f"{m:+.2f} [{lo:+.2f}, {hi:+.2f}]")
            print(f"| {name} | {label} | " + " | ".join(cells) + " |")
    if args.reference:
        print(f"\nPaired avg, model - {args.reference} (scenes paired; each (scene, seed) of a model against "
              f"{args.reference}'s mean over its seeds on that scene):\n")
        ref = models[args.reference]
        ref_by_scene = {}
        for (s, _), r in ref.items():
            ref_by_scene.setdefault(s, []).append(r["avg"])
        for name, rows in models.items():
            if name == args.reference:
                continue
            variant = {u: r["avg"] for u, r in rows.items()}
            reference = {u: float(np.mean(ref_by_scene[u[0]])) for u in variant}
            m, lo, hi = paired_bootstrap_ci(variant, reference)
            print(f"- {name}: {m:+.2f} [{lo:+.2f}, {hi:+.2f}] dB")


if __name__ == "__main__":
    main()
