"""Where the gloss shows: per scene of a controlled-pairs dataset, how many of a surface's points
show a highlight in any of the 32 lattice views (issue 52).

A glossy and a matte dielectric of one colour differ only in their highlights. This measures, on
the exact lattice renders (the upper bound of what any Stage 0 keeps), the per-point cross-view
statistic's brightest-minus-median gain (``gspi.stage2.view_statistics``) over a seeded subset of
each scene's surface points: its median, 90th and 99th percentiles, and the share of points whose
gain exceeds ``HIGHLIGHT_GAIN``. If the median glossy point looks like a matte one, no per-point
reader can order the pair; the cue is in a few points and has to be pooled over the surface.

    python -m experiments.view_dependence.pair_highlights PAIRS_DATA --out experiments/view_dependence/log/pair_highlights.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from gspi.data.controlled_pairs import read_manifest

POINTS_PER_SCENE = 3000
HIGHLIGHT_GAIN = 0.2  # linear luminance above the point's median view: a visible highlight


def highlit_share(peak_gain: np.ndarray) -> float:
    """The share of points whose gain exceeds ``HIGHLIGHT_GAIN``: what counts as a highlit point."""
    return float(np.mean(peak_gain > HIGHLIGHT_GAIN))


def highlight_summary(peak_gain: np.ndarray) -> dict[str, float]:
    """Quantiles of the per-point gain and the share of highlit points (``highlit_share``)."""
    q50, q90, q99 = np.quantile(peak_gain, [0.5, 0.9, 0.99])
    return {"median": float(q50), "q90": float(q90), "q99": float(q99), "share_highlit": highlit_share(peak_gain)}


def scene_highlights(scene_dir: Path, seed: int = 0) -> dict[str, float]:
    from experiments.view_dependence.stage0_probe import lattice_images, surface_subset
    from gspi.stage2.data import read_lattice_cameras
    from gspi.stage2.view_statistics import cross_view_radiance

    _, cams = read_lattice_cameras(scene_dir)
    rgb, depth = lattice_images(scene_dir)
    xyz = surface_subset(scene_dir, POINTS_PER_SCENE, seed)["xyz"].astype(np.float64)
    stats = cross_view_radiance(rgb, depth, cams, xyz)
    return highlight_summary(stats[:, 0])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="a gspi-data preset=controlled_pairs folder (pairs.json)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    pairs = read_manifest(args.data)
    out = {"points_per_scene": POINTS_PER_SCENE, "highlight_gain": HIGHLIGHT_GAIN, "pairs": []}
    for pair in pairs:
        out["pairs"].append({"id": pair["id"], "kind": pair["kind"], "family": pair["family"],
                             "members": {m: scene_highlights(args.data / s) for m, s in pair["scenes"].items()}})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
