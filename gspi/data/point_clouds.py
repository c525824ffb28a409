"""Ground-truth point clouds for Stage II training (paper, "Training vs. Inference Dynamics").

`<scene>/gt_points.npz` holds the unprojection of the stored GT depth of the V = 32 lattice
views (the `train` split, in lattice order), one point per foreground pixel (mask.png = 255):

    xyz      [P, 3] float32  world position = camera centre + pixel_ray * depth / (ray . forward)
                             (`eval.views.pixel_rays`, pixel centres; lies on the SDF surface)
    view     [P]    int32    lattice view index k in 0..V-1 (view id f"{k:03d}"), the source view
                             of Stage II's one-hot condition
    pixel    [P, 2] int32    (row, col) of the source pixel
    rgb      [P, 3] float32  linear HDR radiance of rgb.exr at that pixel (the photometric cue)
    albedo   [P, 3] float32  albedo.png value, sRGB-encoded in [0, 1] (as stored)
    roughness[P]    float32  roughness.png value, linear in [0, 1]
    metallic [P]    float32  metallic.png value, linear in [0, 1]

All values are read back from the stored files, so they equal what a loader of the layout sees.
The file is written with fixed zip timestamps (`numpy.savez` stamps the current time), so the
same seed gives the same bytes.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import torch

from eval.common.layout import Scene, read_view_file
from eval.views import pixel_rays

POINT_FIELDS = ("xyz", "view", "pixel", "rgb", "albedo", "roughness", "metallic")


def unproject_depth(K: np.ndarray, w2c: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """World points of every pixel from OpenCV camera-space z.

    Args:
        K: [3, 3]; w2c: [4, 4]; depth: [H, W] camera z (world units).
    Returns:
        [H, W, 3] float32 world positions (meaningless where depth = 0).
    """
    h, w = depth.shape
    rays = pixel_rays(K, w2c, h, w).double()                        # [H, W, 3]
    forward = torch.as_tensor(w2c[2, :3], dtype=torch.float64)
    centre = torch.as_tensor(np.linalg.inv(w2c)[:3, 3], dtype=torch.float64)
    t = torch.as_tensor(depth, dtype=torch.float64) / (rays @ forward)
    return (centre + rays * t[..., None]).float().numpy()


def scene_point_cloud(scene: Scene, split: str = "train") -> dict[str, np.ndarray]:
    """Point cloud of one scene from its stored files (see module docstring)."""
    parts: dict[str, list] = {k: [] for k in POINT_FIELDS}
    for k, view in enumerate(scene.split_views(split)):
        vdir = scene.view_dir(split, view.id)
        mask = read_view_file(vdir, "mask.png")[..., 0] > 0.5
        depth = read_view_file(vdir, "depth.exr")[..., 0]
        mask &= depth > 0
        rows, cols = np.nonzero(mask)
        parts["xyz"].append(unproject_depth(view.K, view.w2c, depth)[mask])
        parts["view"].append(np.full(len(rows), k, dtype=np.int32))
        parts["pixel"].append(np.stack([rows, cols], axis=-1).astype(np.int32))
        parts["rgb"].append(read_view_file(vdir, "rgb.exr")[mask])
        parts["albedo"].append(read_view_file(vdir, "albedo.png")[mask])
        parts["roughness"].append(read_view_file(vdir, "roughness.png")[mask][:, 0])
        parts["metallic"].append(read_view_file(vdir, "metallic.png")[mask][:, 0])
    return {k: np.concatenate(v) for k, v in parts.items()}


def write_npz_deterministic(path: str | Path, arrays: dict[str, np.ndarray]) -> Path:
    """Like `numpy.savez_compressed`, with fixed member timestamps (byte-reproducible)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)
    return path


def write_scene_point_cloud(scene: Scene) -> Path:
    """Write `<scene>/gt_points.npz` from the lattice (train) views."""
    return write_npz_deterministic(scene.root / "gt_points.npz", scene_point_cloud(scene))
