"""The Stage I point cloud: source-anchored points, saved as `points.npz`.

Every point keeps the lattice view v* it was unprojected from, its pixel (row, col) there and
the linear RGB observed at that pixel (paper, "Microscopic Source-Anchored Photometric Cues"),
so per-point predictions can be scattered back into per-view maps.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from eval.colorspace import linear_to_srgb

NUM_LATTICE_VIEWS = 32


@dataclass
class PointCloud:
    xyz: np.ndarray    # [P, 3] float32 world
    view: np.ndarray   # [P] int32, source lattice view v*
    pixel: np.ndarray  # [P, 2] int32, (row, col) in view v*
    rgb: np.ndarray    # [P, 3] float32, linear radiance observed at that pixel

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, keep: np.ndarray) -> "PointCloud":
        return PointCloud(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, **{f.name: getattr(self, f.name) for f in fields(self)})
        return path

    @classmethod
    def load(cls, path: str | Path) -> "PointCloud":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: point cloud file not found")
        with np.load(path) as data:
            missing = [f.name for f in fields(cls) if f.name not in data]
            if missing:
                raise ValueError(f"{path}: not a Stage I point cloud (missing {missing})")
            return cls(**{f.name: data[f.name] for f in fields(cls)})


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
