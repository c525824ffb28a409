"""Stage II's conditions of a scene read from a 2DGS asset's lattice renders instead of the GT renders.

Stage II is trained on a scene's GT point cloud with conditions read from the scene's lattice
views (``train/<k>/rgb.exr``: the global prior's images; ``gt_points.npz["rgb"]``: each point's
Top-RGB, the colour of its source view at its stored pixel). In a run the same conditions come
from the reconstructed asset's lattice renders (Stage I). This writes a scene folder whose
conditions are the asset's, everything else (points, materials, cameras, depth, masks) the
scene's own, as symlinks:

- ``top_rgb``: ``gt_points.npz`` with ``rgb`` read from the asset's render of each point's
  source view at its stored pixel;
- ``prior``: the lattice ``rgb.exr`` files replaced by the asset's renders.

Used by ``gspi.recon.reconstructed_pool`` (both conditions: a training pool as the paper trains,
on lattice renders of reconstructed assets); ``conditions`` may also swap one at a time.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

LATTICE_SPLIT = "train"  # a generated scene's train views are the canonical lattice (view k = camera k)
CONDITIONS = ("top_rgb", "prior")
# Stage I of a pool scene's asset, kept beside it (gspi.stage1.pool_clouds writes, the light condition reads)
ASSET_STAGE1_POINTS = Path("asset") / "stage1" / "points.npz"    # gspi.point_cloud.PointCloud
ASSET_STAGE1_RENDERS = Path("asset") / "stage1" / "renders.npz"  # gspi.gaussians.lattice_render.LatticeRenders


def link_tree(src: Path, dst: Path, replace: set[str]) -> None:
    """``dst`` mirrors ``src`` by symlinks, except the relative paths in ``replace`` (and the
    folders holding them), which the caller writes."""
    dst.mkdir(parents=True, exist_ok=True)
    for item in src.iterdir():
        rel = item.name
        inner = {r.split("/", 1)[1] for r in replace if r.startswith(rel + "/")}
        if item.is_dir() and inner:
            link_tree(item, dst / rel, inner)
        elif rel not in replace and not (dst / rel).exists():
            os.symlink(item.resolve(), dst / rel)


def lattice_view_ids(scene_dir: Path) -> list[str]:
    from eval.common.layout import read_scene

    return [v.id for v in read_scene(scene_dir).split_views(LATTICE_SPLIT)]


def write_asset_conditions(scene_dir: Path, asset_rgb: np.ndarray, dst: Path,
                           conditions: tuple[str, ...] = CONDITIONS) -> Path:
    """``dst`` (a scene folder) = ``scene_dir`` with ``conditions`` read from ``asset_rgb``."""
    from eval.common.imageio import write_exr

    scene_dir, dst = Path(scene_dir), Path(dst)
    unknown = set(conditions) - set(CONDITIONS)
    if unknown:
        raise ValueError(f"conditions {sorted(unknown)}: known are {list(CONDITIONS)}")
    views = lattice_view_ids(scene_dir)
    if len(views) != len(asset_rgb):
        raise ValueError(f"{scene_dir}: {len(views)} {LATTICE_SPLIT} views but the asset renders "
                         f"{len(asset_rgb)} lattice views")
    replace = set()
    if "top_rgb" in conditions:
        replace.add("gt_points.npz")
    if "prior" in conditions:
        replace.update(f"{LATTICE_SPLIT}/{v}/rgb.exr" for v in views)
    link_tree(scene_dir, dst, replace)
    if "top_rgb" in conditions:
        pts = dict(np.load(scene_dir / "gt_points.npz"))
        rows, cols = pts["pixel"][:, 0], pts["pixel"][:, 1]
        pts["rgb"] = asset_rgb[pts["view"], rows, cols].astype(pts["rgb"].dtype)
        np.savez(dst / "gt_points.npz", **pts)
    if "prior" in conditions:
        for k, v in enumerate(views):
            write_exr(dst / LATTICE_SPLIT / v / "rgb.exr", asset_rgb[k].astype(np.float32))
    return dst
