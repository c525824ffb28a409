"""Issue 42: where a run's roughness goes wrong, asset by asset (the rule's limiting column).

For each scene of a dataset, the mean and spread of GT roughness and of each run's predicted
roughness over the foreground pixels of the scored ``test`` views (the dataset's ``mask.png``,
as the protocol masks), and each run's roughness PSNR from its ``eval/eval_meta.json``. A run
that predicts a glossy finish where the GT is matte shows as a predicted mean far below the GT
mean; a constant (no decomposition) shows as zero spread.

    python experiments/training_pools/roughness_bias.py --data data/real \\
        parts=RUNS_REAL/method=gspi,... no_decomposition=RUNS_REAL/method=no_decomposition
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from eval.common.layout import read_splits, read_view_file


def view_masks(data_scene: Path) -> dict[str, np.ndarray]:
    """The foreground mask of every ``test`` view of a dataset scene, by view folder name."""
    return {v.name: read_view_file(v, "mask.png")[..., 0] > 0.5 for v in sorted((data_scene / "test").iterdir())}


def foreground_values(scene_dir: Path, masks: dict[str, np.ndarray]) -> np.ndarray:
    """Roughness on the masked pixels of ``scene_dir/test/<view>/roughness.png`` (GT or prediction)."""
    return np.concatenate([read_view_file(scene_dir / "test" / name, "roughness.png")[..., 0][mask]
                           for name, mask in masks.items()])


def roughness_rows(data: Path, runs: dict[str, Path]) -> list[dict]:
    """One row per test scene: GT mean/std, and per run its mean/std and roughness PSNR."""
    scores = {name: json.loads((run / "eval" / "eval_meta.json").read_text())["per_scene"]
              for name, run in runs.items()}
    rows = []
    for scene in read_splits(data)["test"]:
        masks = view_masks(data / scene)  # read once, applied to the GT and to every run
        gt = foreground_values(data / scene, masks)
        row = {"scene": scene, "gt": (float(gt.mean()), float(gt.std()))}
        for name, run in runs.items():
            pred = foreground_values(run / "predictions" / scene, masks)
            row[name] = (float(pred.mean()), float(pred.std()), scores[name][scene]["roughness"]["psnr"])
        rows.append(row)
    return rows


def render(rows: list[dict], names: list[str]) -> str:
    head = "| scene | GT mean (std) | " + " | ".join(f"{n}: mean (std), PSNR" for n in names) + " |"
    lines = [head, "|" + "---|" * (2 + len(names))]
    for r in rows:
        cells = [f"{r[n][0]:.2f} ({r[n][1]:.2f}), {r[n][2]:.2f}" for n in names]
        lines.append(f"| {r['scene']} | {r['gt'][0]:.2f} ({r['gt'][1]:.2f}) | " + " | ".join(cells) + " |")
    means = [f"{np.mean([r[n][0] for r in rows]):.2f}, {np.mean([r[n][2] for r in rows]):.2f}" for n in names]
    lines.append(f"| mean | {np.mean([r['gt'][0] for r in rows]):.2f} | " + " | ".join(means) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="the dataset the runs scored")
    parser.add_argument("runs", nargs="+", help="NAME=RUN_DIR (a gspi-run job folder)")
    args = parser.parse_args(argv)
    runs = {}
    for item in args.runs:
        name, sep, path = item.partition("=")
        if not sep or not name:
            parser.error(f"expected NAME=RUN_DIR, got {item!r}")
        runs[name] = Path(path)
        if not (runs[name] / "eval" / "eval_meta.json").is_file():
            parser.error(f"{name}: {runs[name]} has no eval/eval_meta.json (not a scored gspi-run job folder)")
    print(render(roughness_rows(args.data, runs), list(runs)))


if __name__ == "__main__":
    main()
