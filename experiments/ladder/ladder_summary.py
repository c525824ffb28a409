"""The ladder's table: each rung over its seeds, per channel, per material class, metal IoU.

Reads ``scores.json`` folders (format gspi-points-eval) of ``experiments.ladder.ladder`` rungs and of
``gspi.stage2.evaluate_points`` (R5); the no-decomposition baseline (R0) is the same in every
folder of one evaluation and is read once. For each rung: the mean over seeds of the per-seed
scene means (PSNR dB) per channel and their average, the seed spread (max - min of the per-seed
average), the metallic PSNR and metal IoU over the metal-class scenes, and the average per
material class.
"""
from __future__ import annotations

import json
from pathlib import Path

import re

import numpy as np

from experiments.ladder.points_breakdown import MATERIAL_CLASSES as CLASSES
from experiments.ladder.points_breakdown import material_class as scene_class
from eval.records.points_scores import BASELINE_KEY as BASELINE
from eval.tables.build import AVG_CHANNELS as CHANNELS


def rung_of(data: dict) -> str:
    """A folder's rung: the ladder's own name; for a diffusion model scored by evaluate_points,
    its run folder's name before ``_s<seed>`` when it names a rung (``runs/ladder/r5skip_s0`` ->
    ``r5skip``, ``r6_s1`` -> ``r6``), else r5."""
    if "ladder" in data:
        return str(data["ablation"])
    run = Path(str(data.get("checkpoint", ""))).parent.name
    stem, sep, seed = run.rpartition("_s")
    return stem if sep and seed.isdigit() and re.fullmatch(r"r\d+[a-z0-9_]*", stem) else "r5"


def seed_row(per_scene: dict, metal_iou: dict) -> dict[str, float]:
    """One evaluated model: the scene means it is summarised by."""
    scenes = sorted(per_scene)
    row = {c: float(np.mean([per_scene[s][c]["psnr"] for s in scenes])) for c in CHANNELS}
    row["avg"] = float(np.mean([row[c] for c in CHANNELS]))
    metal = [s for s in scenes if scene_class(s) == "metal"]
    if metal:
        row["metallic@metal"] = float(np.mean([per_scene[s]["metallic"]["psnr"] for s in metal]))
        ious = [metal_iou.get(s) for s in metal]
        row["metal_iou@metal"] = float(np.mean([0.0 if v is None else v for v in ious]))
    for cls in CLASSES:
        group = [s for s in scenes if scene_class(s) == cls]
        if group:
            row[f"avg@{cls}"] = float(np.mean([np.mean([per_scene[s][c]["psnr"] for c in CHANNELS]) for s in group]))
    return row


def summarise(folders: list[Path]) -> dict[str, dict]:
    """{rung: {"seeds": [...], "mean": {key: value}, "spread": avg max - min}}."""
    rows: dict[str, list[dict]] = {}
    seeds: dict[str, list] = {}
    for folder in folders:
        data = json.loads((Path(folder) / "scores.json").read_text())
        iou = data.get("metal_iou", {})
        rung = rung_of(data)
        rows.setdefault(rung, []).append(seed_row(data["per_scene"]["stage2"], iou.get("stage2", {})))
        seeds.setdefault(rung, []).append(data.get("train_seed"))
        if BASELINE not in rows:
            rows[BASELINE] = [seed_row(data["per_scene"][BASELINE], iou.get(BASELINE, {}))]
            seeds[BASELINE] = [None]
    out = {}
    for rung, rs in rows.items():
        keys = sorted(set().union(*rs))
        avgs = [r["avg"] for r in rs]
        out[rung] = {"seeds": seeds[rung], "mean": {k: float(np.mean([r[k] for r in rs if k in r])) for k in keys},
                     "spread": float(max(avgs) - min(avgs))}
    return out


def to_markdown(summary: dict[str, dict]) -> str:
    cols = ["albedo", "roughness", "metallic", "avg", "spread", "metallic@metal", "metal_iou@metal",
            *[f"avg@{c}" for c in CLASSES]]
    lines = ["| rung | seeds | " + " | ".join(cols) + " |", "|---" * (len(cols) + 2) + "|"]
    order = sorted(summary, key=lambda r: ("0" if r == BASELINE else r))
    for rung in order:
        s = summary[rung]
        cells = []
        for c in cols:
            v = s["spread"] if c == "spread" else s["mean"].get(c)
            cells.append("" if v is None else f"{v:.2f}")
        name = "R0 no decomposition" if rung == BASELINE else rung.upper()
        lines.append(f"| {name} | {len(s['seeds'])} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def print_summary(folders: list[Path]) -> None:
    print(to_markdown(summarise(folders)))


def unit_values(folders: list[Path], key: str = "avg") -> dict[str, dict[tuple, float]]:
    """{rung: {(scene, seed): PSNR}} of one channel (or "avg"); the baseline under every seed."""
    out: dict[str, dict[tuple, float]] = {}
    base: dict[str, float] = {}
    for folder in folders:
        data = json.loads((Path(folder) / "scores.json").read_text())
        rung = rung_of(data)
        seed = data.get("train_seed")
        for scene, ch in data["per_scene"]["stage2"].items():
            out.setdefault(rung, {})[(scene, seed)] = _value(ch, key)
        for scene, ch in data["per_scene"][BASELINE].items():
            base[scene] = _value(ch, key)
    seeds = {s for values in out.values() for _, s in values}
    out[BASELINE] = {(scene, s): v for scene, v in base.items() for s in seeds}
    return out


def _value(channels: dict, key: str) -> float:
    if key == "avg":
        return float(np.mean([channels[c]["psnr"] for c in CHANNELS]))
    return float(channels[key]["psnr"])


def versus(folders: list[Path], reference: str, key: str = "avg", scenes: str | None = None) -> dict[str, tuple]:
    """{rung: (mean, lo, hi)} paired difference rung - reference over (scene, seed) units
    (95 % percentile bootstrap, eval.stats); ``scenes``: only scenes of that material class."""
    values = unit_values(folders, key)
    if scenes is not None:
        values = {r: {u: v for u, v in vs.items() if scene_class(u[0]) == scenes} for r, vs in values.items()}
    ref = values[reference]
    return {rung: _ci(vs, ref) for rung, vs in sorted(values.items()) if rung != reference}


def _ci(variant: dict, reference: dict) -> tuple:
    """The paired mean and CI; with a single pair, its difference and no interval (NaN)."""
    from eval.stats import paired_bootstrap_ci, paired_differences

    diffs = paired_differences(variant, reference)
    if len(diffs) < 2:
        mean = float(np.mean(list(diffs.values()))) if diffs else float("nan")
        return mean, float("nan"), float("nan")
    return paired_bootstrap_ci(variant, reference)
