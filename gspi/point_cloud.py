"""The Stage I point cloud: source-anchored points, saved as `points.npz`.

Every point keeps the lattice view v* it was unprojected from, its pixel (row, col) there and
the linear RGB observed at that pixel (paper, "Microscopic Source-Anchored Photometric Cues"),
so per-point predictions can be scattered back into per-view maps.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from eval.common.colorspace import linear_to_srgb
from gspi.data.lattice import NUM_LATTICE_VIEWS



POINT_FIELDS = ("xyz", "view", "pixel", "rgb")  # per-point arrays, in this order


@dataclass
class PointCloud:
    xyz: np.ndarray    # [P, 3] float32 world
    view: np.ndarray   # [P] int32, source lattice view v*
    pixel: np.ndarray  # [P, 2] int32, (row, col) in view v*
    rgb: np.ndarray    # [P, 3] float32, linear radiance observed at that pixel
    # (height, width) in px of the lattice views the pixels index; None if unknown
    image_size: Optional[tuple[int, int]] = None

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, keep: np.ndarray) -> "PointCloud":
        """The points selected by a boolean mask or index array `keep` (same image size)."""
        return PointCloud(**{name: getattr(self, name)[keep] for name in POINT_FIELDS},
                          image_size=self.image_size)

    def save(self, path: str | Path) -> Path:
        """Writes `path` (.npz): the per-point arrays and, if known, `image_size` [2] (H, W)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {name: getattr(self, name) for name in POINT_FIELDS}
        if self.image_size is not None:
            arrays["image_size"] = np.asarray(self.image_size, dtype=np.int64)
        np.savez_compressed(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "PointCloud":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: point cloud file not found")
        with np.load(path) as data:
            missing = [name for name in POINT_FIELDS if name not in data]
            if missing:
                raise ValueError(f"{path}: not a Stage I point cloud (missing {missing})")
            size = tuple(int(x) for x in data["image_size"]) if "image_size" in data else None
            return cls(**{name: data[name] for name in POINT_FIELDS}, image_size=size)


def top_rgb(rgb_linear: Tensor) -> Tensor:
    """The 3-dim Top-RGB condition: observed linear radiance -> clamp to [0, 1] -> sRGB."""
    return linear_to_srgb(rgb_linear.clamp(0.0, 1.0))


def local_condition(points: PointCloud, *, num_views: int = NUM_LATTICE_VIEWS,
                    with_view_onehot: bool = True) -> Tensor:
    """Paper Eq. (per-point condition): [Top-RGB || one-hot(v*)], [P, 3 + 32] float32."""
    rgb = top_rgb(torch.from_numpy(points.rgb).float())
    if not with_view_onehot:
        return rgb
    onehot = torch.nn.functional.one_hot(torch.from_numpy(points.view).long(), num_views)
    return torch.cat([rgb, onehot.float()], dim=-1)


def scatter_pixel_values(view: np.ndarray, pixel: np.ndarray, values: np.ndarray, *, height: int,
                         width: int, num_views: int = NUM_LATTICE_VIEWS) -> tuple[np.ndarray, np.ndarray]:
    """Per-point values -> per-view maps through each point's (view, row, col).

    Args:
        view: [P] int source view in 0..num_views-1; pixel: [P, 2] int (row, col);
        values: [P, C] float.
    Returns:
        maps [V, H, W, C] float32 (0 where no point landed; the MEAN where several points share a
        pixel: Stage I gives one point per pixel, so normally a plain copy) and
        hit_mask [V, H, W] bool (pixels that received at least one point).
    Raises:
        ValueError: shapes disagree or a view / pixel index is out of range.
    """
    view, pixel = np.asarray(view, dtype=np.int64), np.asarray(pixel, dtype=np.int64)
    values = np.asarray(values)
    if values.ndim != 2 or len(values) != len(view) or pixel.shape != (len(view), 2):
        raise ValueError(f"scatter: need values [P, C], view [P], pixel [P, 2]; got values "
                         f"{values.shape}, view {view.shape}, pixel {pixel.shape}")
    bad = (view < 0) | (view >= num_views) | (pixel[:, 0] < 0) | (pixel[:, 0] >= height) | \
          (pixel[:, 1] < 0) | (pixel[:, 1] >= width)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"scatter: {int(bad.sum())} point(s) outside {num_views} views of {height}x{width} px "
                         f"(first: view {view[i]}, pixel {tuple(pixel[i])}); were they extracted at this size?")
    flat = (view * height + pixel[:, 0]) * width + pixel[:, 1]
    size = num_views * height * width
    counts = np.bincount(flat, minlength=size)
    hit = counts > 0
    maps = np.zeros((size, values.shape[1]), dtype=np.float64)
    for c in range(values.shape[1]):  # bincount sums duplicates (np.add.at is ~10x slower)
        maps[:, c] = np.bincount(flat, weights=values[:, c], minlength=size)
    maps[hit] /= counts[hit, None]
    return (maps.astype(np.float32).reshape(num_views, height, width, -1),
            hit.reshape(num_views, height, width))


def nearest_fill(points_sub: Union[PointCloud, np.ndarray], values_sub: np.ndarray,
                 points_all: Union[PointCloud, np.ndarray]) -> np.ndarray:
    """Values of a subsample propagated to the whole cloud: each point takes the value of its
    nearest subsample point in 3D (scipy cKDTree; ties go to the lower index).

    Args:
        points_sub: S points (PointCloud or xyz [S, 3]); values_sub: [S, C];
        points_all: P points (PointCloud or xyz [P, 3]).
    Returns:
        [P, C] values (exact copies for points that are in the subsample).
    """
    xyz_sub = np.asarray(getattr(points_sub, "xyz", points_sub), dtype=np.float64)
    xyz_all = np.asarray(getattr(points_all, "xyz", points_all), dtype=np.float64)
    values_sub = np.asarray(values_sub)
    if len(xyz_sub) == 0 or len(values_sub) != len(xyz_sub):
        raise ValueError(f"nearest_fill: need a non-empty subsample with one value row per point; got "
                         f"{len(xyz_sub)} points and values {values_sub.shape}")
    _, idx = cKDTree(xyz_sub).query(xyz_all, k=1)
    return values_sub[idx]
