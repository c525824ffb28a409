"""Where a Stage II model wins or loses: Table 2's measure broken down by scene group.

For folders of Stage II point-cloud evaluations (`scores.json`, format gspi-points-eval, see
`eval.records.points_scores`), the mean PSNR of each model (its ablation) and of the no-decomposition
baseline per group of scenes: by material class (the scene name's suffix, e.g.
`p0230_multipart_metal` -> `metal`), by image size (the scene's `scene.json` width: the pool
mixes the presets' 64 and 128 px, hence their point densities) and per channel.

    python -m experiments.ladder.points_breakdown runs/t2cpu/*/eval_heldout
    python -m experiments.ladder.points_breakdown runs/t2cpu/*/eval_heldout --channel metallic   # groups of one channel
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from eval.records.points_scores import BASELINE_KEY, MODEL_KEY, SCORES_NAME, find_points_folders, read_points_scores
from eval.tables.build import AVG_CHANNELS as CHANNELS

from gspi.data.procedural.materials import MATERIAL_CLASSES  # the one list (issue 40)


def material_class(scene: str) -> str:
    """The material class a scene name ends with ("other" if none); the longest match, so
    ``..._painted_metal`` is painted_metal, not metal."""
    return max((c for c in MATERIAL_CLASSES if scene.endswith("_" + c)), key=len, default="other")


def image_size(data_dir: Path, scene: str) -> int | None:
    path = Path(data_dir) / scene / "scene.json"
    return int(json.loads(path.read_text())["width"]) if path.is_file() else None


def breakdown(folders: list[Path], channel: str | None = None) -> dict[str, dict[str, float]]:
    """{row: {group: mean PSNR}}; rows = ablations (+ the baseline), groups = "class=...",
    "size=...", and "<channel>" (all scenes); in the class and size groups a scene's value is
    the mean of its three channels, or of `channel` alone when given."""
    if channel is not None and channel not in CHANNELS:
        raise ValueError(f"channel {channel!r}: one of {', '.join(CHANNELS)}")
    rows: dict[str, dict[str, list[float]]] = {}
    for folder in folders:
        data = read_points_scores(folder / SCORES_NAME)
        sizes = {s: image_size(Path(data["data"]), s) for s in data["scenes"]}
        sources = [(str(data["ablation"]), MODEL_KEY)]
        if BASELINE_KEY not in rows:  # the same in every folder: counted once
            sources.append((BASELINE_KEY, BASELINE_KEY))
        for row, key in sources:
            groups = rows.setdefault(row, {})
            for scene, channels in data["per_scene"][key].items():
                avg = float(np.mean([channels[c]["psnr"] for c in ([channel] if channel else CHANNELS)]))
                groups.setdefault(f"class={material_class(scene)}", []).append(avg)
                groups.setdefault(f"size={sizes[scene]}", []).append(avg)
                for c in CHANNELS:
                    groups.setdefault(c, []).append(float(channels[c]["psnr"]))
    return {row: {g: float(np.mean(v)) for g, v in sorted(groups.items())} for row, groups in rows.items()}


def to_markdown(table: dict[str, dict[str, float]]) -> str:
    groups = sorted({g for row in table.values() for g in row})
    lines = ["| model | " + " | ".join(groups) + " |", "|---" * (len(groups) + 1) + "|"]
    for row in sorted(table, key=lambda r: (r == BASELINE_KEY, r)):
        lines.append(f"| {row} | " + " | ".join(f"{table[row].get(g, float('nan')):.2f}" for g in groups) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+")
    parser.add_argument("--channel", choices=CHANNELS, default=None,
                        help="class/size groups of this channel's PSNR (default: the mean of the three)")
    args = parser.parse_args(argv)
    print(to_markdown(breakdown(find_points_folders(args.folders), args.channel)))


if __name__ == "__main__":
    main()
