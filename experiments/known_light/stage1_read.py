"""The training-free read-out end to end on the held-out pool's Stage 0 assets (issue 66, items 3
and 5 under the conditions users' assets have): Stage I's cloud and renders of each scene's
``recon=fast`` asset, the light estimated among the pool's capture environments and each point's
material read (``method=light_fit``'s ``predict_light_fit``), in the scene's photos (the asset for
geometry and visibility) and, with ``--renders``, in the asset's renders; scored on the generated
cloud by Table 2's measure (``score_generated_points``) beside no decomposition on the same cloud
(Top-RGB, the recorded training constants), with the metal class IoU over the lattice pixels.

    python -m experiments.known_light.stage1_read HELDOUT_TEST RHELDOUT OUT.json --baseline SCORES.json [--renders]

HELDOUT_TEST: the GT scenes (photos, truth); RHELDOUT: their reconstructed pool (``asset/point_cloud.ply``).
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch

log = logging.getLogger(__name__)


def metal_iou(points, metallic: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float | None:
    """IoU of {metallic > 0.5} between the prediction scattered into the lattice views and the GT
    maps ``gt`` [V, H, W, 5] (``read_gt_view_maps``), over the pixels both the GT ``mask`` [V, H, W]
    and the cloud cover; None when neither has metal."""
    from gspi.stage2.score_generated import scatter_point_values

    pred, hit = scatter_point_values(points, metallic[:, None], height=gt.shape[1], width=gt.shape[2],
                                     num_views=len(mask))
    truth = gt[..., 4] > 0.5
    cover = mask & hit
    p, t = pred[..., 0][cover] > 0.5, truth[cover]
    union = int(np.count_nonzero(p | t))
    return None if union == 0 else float(np.count_nonzero(p & t)) / union


def asset_stage1(scene_dir: Path, asset_ply: Path):
    """(Stage I's cloud, its lattice renders, the scene's photos at them or None, which views) of
    a scene's Stage 0 asset, as gspi-run builds them (the pool's scenes are 64 or 128 px)."""
    from eval.common.layout import read_scene
    from gspi.gaussians.ply import read_ply
    from gspi.stage1.config import Stage1Config
    from gspi.stage1.extract import extract_point_cloud
    from gspi.stage2.light_views import lattice_photos

    points, renders, _ = extract_point_cloud(read_ply(asset_ply),
                                             Stage1Config(image_size=read_scene(scene_dir).width))
    photos, views = lattice_photos(scene_dir, renders)
    return points, renders, photos, views


def pending_scenes(assets: Path, done: dict, every: int = 1) -> list[str]:
    """The names of the reconstructed pool ``assets`` (``<scene>/asset/point_cloud.ply``), sorted,
    every ``every``-th, that ``done["scenes"]`` (a resumable read's record) does not hold yet."""
    names = sorted(p.parent.parent.name for p in assets.glob("*/asset/point_cloud.ply"))[::every]
    return [n for n in names if n not in done["scenes"]]


def gt_metal_fraction(scene_dir: Path) -> float:
    """The share of a scene's GT surface points that are metal (metallic > 0.5)."""
    with np.load(scene_dir / "gt_points.npz") as npz:
        return float((npz["metallic"] > 0.5).mean())


def paired_channel_diffs(variant: dict, reference: dict, channels) -> str:
    """``"albedo +0.14 [+0.06, +0.22], ..."``: per channel the mean paired difference (variant -
    reference, each {scene: {channel: PSNR}}) over scenes with its 95 % bootstrap CI."""
    from eval.stats import paired_bootstrap_ci

    parts = []
    for c in channels:
        d, lo, hi = paired_bootstrap_ci({n: r[c] for n, r in variant.items()}, {n: r[c] for n, r in reference.items()})
        parts.append(f"{c} {d:+.2f} [{lo:+.2f}, {hi:+.2f}]")
    return ", ".join(parts)


def read_or_table(doc: str, argv: list[str] | None, read_scenes, table, table_md: Path, *,
                  table_files: tuple[str, ...] = ("TRAIN", "HELDOUT"), every: bool = True) -> None:
    """The door of a resumable per-scene read (``SCENES ASSETS OUT --baseline SCORES.json``, and
    ``--every n`` when ``every``) with a ``--table`` mode: the table of finished reads (the record
    files named ``table_files``), printed and written to ``table_md``; else ``read_scenes(args)``
    on one torch thread."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("data", type=Path, nargs="?")
    ap.add_argument("assets", type=Path, nargs="?")
    ap.add_argument("out", type=Path, nargs="?")
    ap.add_argument("--baseline", type=Path, help="a scores.json whose baseline constants to reuse")
    if every:
        ap.add_argument("--every", type=int, default=1, help="read every n-th scene (sorted by name)")
    ap.add_argument("--table", type=Path, nargs=len(table_files), metavar=table_files, default=None,
                    help=f"print the table of finished reads (writes {table_md.parent.name}/{table_md.name})")
    args = ap.parse_args(argv)
    if args.table:
        text = table(*args.table)
        table_md.write_text(text)
        print(text)
        return
    if not (args.data and args.assets and args.out and args.baseline):
        ap.error("SCENES ASSETS OUT and --baseline are needed to read")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    read_scenes(args)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("assets", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--baseline", type=Path, required=True, help="a scores.json whose baseline constants to reuse")
    ap.add_argument("--renders", action="store_true", help="also read in the asset's renders")
    ap.add_argument("--normal-search", type=float, nargs="*", default=None,
                    help="also read in the photos with a normal search (rings in degrees, e.g. 4 8)")
    ap.add_argument("--normal-profile", type=int, default=None,
                    help="with --normal-search, read instead with each cell the best of this many searched normals")
    ap.add_argument("--no-plain", action="store_true", help="skip the plain read in the photos (read elsewhere)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(1)
    from eval.common.layout import read_scene
    from eval.lpips.net import load_lpips
    from gspi.data.gt_maps import read_gt_view_maps
    from gspi.stage2.data import srgb_top_rgb
    from gspi.stage2.evaluate_points import recorded_constants
    from gspi.stage2.light_condition import candidate_lights
    from gspi.stage2.light_fit import LightFitConfig, predict_light_fit
    from gspi.stage2.score_generated import score_generated_points

    rough, metal = recorded_constants(args.baseline)
    cfg = LightFitConfig()
    candidates = candidate_lights(cfg.candidates, cfg.env_height)
    net = load_lpips()
    done = json.loads(args.out.read_text()) if args.out.is_file() else {"scenes": {}}
    done.update(baseline_constants={"roughness": rough, "metallic": metal}, config=str(cfg))
    for name, row in done["scenes"].items():  # rows of an earlier version lack their truth
        row.setdefault("capture_env", read_scene(args.data / name).capture_env)
    for name in pending_scenes(args.assets, done):
        t0 = time.perf_counter()
        scene_dir = args.data / name
        points, renders, photos, views = asset_stage1(scene_dir, args.assets / name / "asset" / "point_cloud.ply")
        nodec = np.c_[srgb_top_rgb(points.rgb), np.full((len(points), 2), [rough, metal], dtype=np.float32)]
        preds = {"no_decomposition": (nodec, None)}
        if not args.no_plain:
            preds["photos"] = predict_light_fit(points, renders, cfg, candidates, photos)
        if args.renders:
            preds["renders"] = predict_light_fit(points, renders, cfg, candidates, None)
        if args.normal_search:
            from dataclasses import replace

            searched = replace(cfg, normal_search_deg=tuple(args.normal_search), normal_profile=args.normal_profile or 1)
            key = "photos_normal_profile" if args.normal_profile else "photos_normal_search"
            preds[key] = predict_light_fit(points, renders, searched, candidates, photos)
        gt, mask = read_gt_view_maps(scene_dir)  # read once for every prediction's metal IoU
        row = {"views": views, "capture_env": read_scene(scene_dir).capture_env,
               "seconds": round(time.perf_counter() - t0, 1)}
        for key, (pbr, stats) in preds.items():
            row[key] = {"scores": score_generated_points(points, pbr, scene_dir, lpips_net=net),
                        "metal_iou": metal_iou(points, pbr[:, 4], gt, mask),
                        **({"light": {k: v for k, v in stats["light"].items() if k != "ranking"}} if stats else {})}
        done["scenes"][name] = row
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(done, indent=1))
        log.info("%s: %s", name, {k: round(v["scores"]["avg"]["psnr"], 2) for k, v in row.items() if isinstance(v, dict)})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(done, indent=1))


if __name__ == "__main__":
    main()
