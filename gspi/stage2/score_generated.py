"""Table 2's measure on a GENERATED point cloud (Stage I's output on a reconstructed asset).

Table 2 scores "attributes predicted on the generated point cloud ... exclusively within the
ground-truth alpha mask". Stage I keeps, for every point, its source lattice view and pixel, so
per-point PBR predictions are scattered back into the 32 lattice views (``scatter_point_values``)
and scored against the scene's GT maps of those views (its ``train`` split IS the lattice) with
the mask = GT mask AND the pixels that received a point. Scoring is
``gspi.stage2.evaluate_points.score_maps``: per view masked PSNR (capped at 60 dB) / SSIM /
LPIPS from ``eval.metrics``, averaged over views; "avg" = mean of the three channels.

The Stage I lattice must be rendered at the scene's own image size (a pixel index means the same
pixel in both); a mismatch raises an error. When Stage II predicts on a subsample
(``stage1.max_points``), ``nearest_fill`` propagates the values to the full cloud first.

    from gspi.point_cloud import PointCloud
    points = PointCloud.load("runs/extract/s002/points.npz")
    scores = score_generated_points(points, pbr, Path("data/small/s002_multipart_ceramic"))

    python -m gspi.stage2.score_generated POINTS_NPZ SCENE_DIR --pbr PRED.npy   # [P, 5] predictions
    python -m gspi.stage2.score_generated POINTS_NPZ SCENE_DIR                   # GT-oracle ceiling

Without ``--pbr`` every point gets the GT values of its nearest GT point (``gt_points.npz``, via
``nearest_fill``): the best any predictor can score on this geometry (its ceiling).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from eval.common.layout import LayoutError
from gspi.data.gt_maps import read_gt_view_maps
from gspi.data.lattice import NUM_LATTICE_VIEWS
from gspi.point_cloud import PointCloud, nearest_fill, scatter_pixel_values

PBR_CHANNELS = 5  # albedo (sRGB-encoded, as stored) 3, roughness 1, metallic 1


def scatter_point_values(points: PointCloud, values: np.ndarray, *, height: int, width: int,
                         num_views: int = NUM_LATTICE_VIEWS) -> tuple[np.ndarray, np.ndarray]:
    """:func:`scatter_pixel_values` through a Stage I cloud's source views and pixels.

    Args:
        points: P points; values: [P, C]. Returns maps [V, H, W, C], hit_mask [V, H, W].
    """
    return scatter_pixel_values(points.view, points.pixel, values, height=height, width=width,
                                num_views=num_views)


def check_lattice_size(points: PointCloud, scene_dir: Path) -> tuple[int, int]:
    """(H, W) of the scene's lattice views; raises if the points were extracted at another size."""
    from gspi.stage2.data import read_lattice_cameras

    scene, _ = read_lattice_cameras(scene_dir)
    size = (scene.height, scene.width)
    if points.image_size is not None and tuple(points.image_size) != size:
        h, w = points.image_size
        raise LayoutError(f"{scene_dir}: scene's lattice views are {size[0]}x{size[1]} px but the point cloud "
                         f"was extracted at {h}x{w} px; rerun gspi-extract with stage1.image_size="
                         f"{size[0]} to score it against this scene")
    return size


def score_generated_points(points: PointCloud, pbr: np.ndarray, scene_dir: Path, *,
                           lpips_net=None) -> dict[str, dict[str, float]]:
    """Table 2's measure of per-point PBR predictions on a generated (Stage I) point cloud.

    Args:
        points: P Stage I points extracted at the scene's image size.
        pbr: [P, 5] predictions in [0, 1]: albedo (sRGB-encoded), roughness, metallic.
        scene_dir: canonical scene folder whose ``train`` split is the 32-view lattice.
        lpips_net: a loaded ``eval.lpips.net`` network (loaded here if None).
    Returns:
        {"albedo" | "roughness" | "metallic" | "avg": {"psnr", "ssim", "lpips"}}, per view masked
        scores averaged over the views with at least one scored pixel.
    Raises:
        ValueError: size mismatch, bad shapes, or no pixel where GT mask and points overlap.
    """
    from eval.lpips.net import load_lpips
    from gspi.stage2.points_measure import CHANNELS, METRICS, score_maps

    scene_dir = Path(scene_dir)
    height, width = check_lattice_size(points, scene_dir)
    pbr = np.asarray(pbr, dtype=np.float32)
    if pbr.shape != (len(points), PBR_CHANNELS):
        raise LayoutError(f"{scene_dir}: pbr must be [P, {PBR_CHANNELS}] = [{len(points)}, {PBR_CHANNELS}], "
                         f"got {pbr.shape}")
    gt, gt_mask = read_gt_view_maps(scene_dir)
    pred, hit = scatter_point_values(points, pbr, height=height, width=width, num_views=len(gt))
    mask = gt_mask & hit
    if not mask.any():
        raise LayoutError(f"{scene_dir}: no point lands inside the GT mask of any lattice view")
    scores = score_maps(pred, gt, mask, lpips_net if lpips_net is not None else load_lpips())
    scores["avg"] = {m: float(np.mean([scores[c][m] for c in CHANNELS])) for m in METRICS}
    return scores


def gt_oracle_pbr(points: PointCloud, scene_dir: Path) -> np.ndarray:
    """[P, 5] GT PBR of each point's nearest GT point (``<scene_dir>/gt_points.npz``)."""
    with np.load(Path(scene_dir) / "gt_points.npz") as gt:
        values = np.c_[gt["albedo"], gt["roughness"], gt["metallic"]]
        return nearest_fill(gt["xyz"], values, points)


def main(argv: list[str] | None = None) -> None:
    import torch

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("points", help="Stage I points.npz")
    parser.add_argument("scene", help="canonical scene folder (train split = the lattice)")
    parser.add_argument("--pbr", help="[P, 5] .npy predictions (default: the GT oracle)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    points = PointCloud.load(args.points)
    pbr = np.load(args.pbr) if args.pbr else gt_oracle_pbr(points, Path(args.scene))
    print(json.dumps(score_generated_points(points, pbr, Path(args.scene)), indent=2))


if __name__ == "__main__":
    from eval.common.errors import run_command

    run_command(main)  # a stated error or Ctrl-C: one line (exit 2 / 130)
