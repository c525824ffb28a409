"""The Stage I point cloud: source-anchored points, saved as `points.npz`.

Every point keeps the lattice view v* it was unprojected from, its pixel (row, col) there and
the linear RGB observed at that pixel (paper, "Microscopic Source-Anchored Photometric Cues"),
so per-point predictions can be scattered back into per-view maps.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from eval.colorspace import linear_to_srgb

NUM_LATTICE_VIEWS = 32


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
