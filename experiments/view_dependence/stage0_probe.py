"""Issue 52's first probe: how much view dependence a Stage 0 config keeps for Stage II to read.

For every scene of a source dataset (its ``train`` views the 32-view lattice, with
``gt_points.npz``) and one or more of its reconstructions (``gspi.recon.reconstructed_pool``
folders, one per Stage 0 config), per surface point (the GT cloud, a seeded subset) over the
lattice views that see it (``gspi.stage2.view_statistics``): the brightest view's luminance
minus the median (``peak_gain``) and the luminance's spread, in the exact renders (GT) and in
the asset's; and per scene the q99 radiance and the fit to the lattice and to held-out photos
(``asset/recon.json``). Writes one JSON of per-scene scores (committed: experiments/view_dependence/log/) and
prints the per-class medians as markdown.

    python -m experiments.view_dependence.stage0_probe SOURCE fast=RECON_FAST fast_view=RECON_VIEW \
        --out experiments/view_dependence/log/stage0_view_dependence.json
    python -m experiments.view_dependence.stage0_probe --table experiments/view_dependence/log/stage0_view_dependence.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

POINTS_PER_SCENE = 4000


def lattice_images(scene_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(linear rgb [V, H, W, 3] float64, depth [V, H, W]) of a scene folder's lattice views."""
    from gspi.stage2.data import read_lattice_views

    rgb, depth = read_lattice_views(scene_dir)
    return rgb.astype(np.float64), depth


def surface_subset(scene_dir: Path, count: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Every per-point array of the scene's GT points (``gt_points.npz``) at a seeded subset of
    ``count`` of them (all if fewer): the one way issue 52's probes pick the points they measure."""
    with np.load(scene_dir / "gt_points.npz") as npz:
        total = len(npz["xyz"])
        keep = np.random.default_rng(seed).choice(total, min(count, total), replace=False)
        return {k: npz[k][keep] for k in npz.files}


def scene_scores(source: Path, recon: Path, seed: int = 0) -> dict:
    """One scene: GT and asset cross-view statistics (medians over points) and recon.json's fit."""
    from gspi.stage2.data import read_lattice_cameras
    from gspi.stage2.view_statistics import cross_view_radiance

    _, cams = read_lattice_cameras(source)
    xyz = surface_subset(source, POINTS_PER_SCENE, seed)["xyz"].astype(np.float64)
    gt_rgb, depth = lattice_images(source)
    asset_rgb, _ = lattice_images(recon)
    out = {}
    for name, images in (("gt", gt_rgb), ("asset", asset_rgb)):
        stats = cross_view_radiance(images, depth, cams, xyz)
        out[f"{name}_peak_gain"] = float(np.median(stats[:, 0]))
        out[f"{name}_peak_gain_q90"] = float(np.quantile(stats[:, 0], 0.9))
        out[f"{name}_spread"] = float(np.median(stats[:, 1]))
    info = json.loads((recon / "asset" / "recon.json").read_text())
    test = info.get("test") or {}
    gen = json.loads((source / "scene.json").read_text()).get("generator", {})
    out.update(material_class=gen.get("material", {}).get("class", "unclassed"),
               gt_q99=info["highlights"]["gt_q99"], asset_q99=info["highlights"]["asset_q99"],
               lattice_db=info["lattice_display_psnr"], heldout_db=test.get("psnr_masked"),
               seconds=info["seconds"]["total"])
    return out


def probe(source: Path, recons: dict[str, Path]) -> dict:
    """{config: {scene: scores}} over the scenes every reconstruction has finished."""
    result = {}
    for config, folder in recons.items():
        done = sorted(p.parent.name for p in folder.glob("*/reconstructed.json"))
        result[config] = {name: scene_scores(source / name, folder / name) for name in done}
        result[config]["_recon"] = json.loads((folder / "reconstructed_pool.json").read_text()).get("recon_config") \
            if (folder / "reconstructed_pool.json").is_file() else None
    return result


TABLE_COLUMNS = ("gt_q99", "asset_q99", "gt_peak_gain", "asset_peak_gain", "gt_spread", "asset_spread",
                 "lattice_db", "heldout_db", "seconds")


def class_table(result: dict, cols: tuple[str, ...] = TABLE_COLUMNS) -> str:
    """Per Stage 0 config and material class: medians over scenes of ``cols`` (scene_scores keys)."""
    lines = ["| Stage 0 | class | scenes | " + " | ".join(cols) + " |", "|---" * (len(cols) + 3) + "|"]
    for config, scenes in result.items():
        by_class: dict[str, list[dict]] = {}
        for name, s in scenes.items():
            if not name.startswith("_"):
                by_class.setdefault(s["material_class"], []).append(s)
        by_class["all"] = [s for group in list(by_class.values()) for s in group]
        for cls, rows in by_class.items():
            cells = []
            for c in cols:
                vals = [r[c] for r in rows if r.get(c) is not None]
                cells.append(f"{np.median(vals):.3f}" if vals else "-")
            lines.append(f"| {config} | {cls} | {len(rows)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", nargs="?", type=Path)
    parser.add_argument("recons", nargs="*", help="NAME=FOLDER: a reconstructed_pool folder per Stage 0 config")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--table", type=Path, help="print the table of a written JSON and stop")
    args = parser.parse_args(argv)
    if args.table:
        print(class_table(json.loads(args.table.read_text())))
        return
    recons = dict(r.split("=", 1) for r in args.recons)
    result = probe(args.source, {k: Path(v) for k, v in recons.items()})
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    print(class_table(result))


if __name__ == "__main__":
    main()
