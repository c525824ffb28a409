"""The staged per-view PBR targets of Stage III (paper: A~_v, R~_v, M~_v).

Stage II predicts (albedo, roughness, metallic) per point; every Stage I point keeps its source
lattice view v* and pixel (row, col), so the predictions scatter back into V per-view maps, with
the cameras of Stage I's renders (``LatticeRenders``: any lattice Stage I was configured with).
Pixels that received no point (background, or foreground removed by Stage I's filters) are
INVALID, unless a silhouette is given: then invalid pixels inside it are FILLED with the value
of the nearest valid pixel of the same view (``scipy.ndimage.distance_transform_edt`` indices)
and marked valid. Arrays are numpy (they are an artifact; :meth:`StagedTargets.tensors` gives
torch views).

``scene_targets`` builds the same structure from a canonical scene's ground-truth maps (an
oracle Stage II: the upper bound of Stage III).
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Optional

import numpy as np
import torch
from scipy import ndimage

from eval.common.layout import Scene
from gspi.data.gt_maps import read_gt_view_maps
from gspi.gaussians.lattice_render import LatticeRenders
from gspi.point_cloud import PointCloud, scatter_pixel_values


@dataclass
class StagedTargets:
    """V per-view material targets, all numpy.

    Attributes:
        albedo: [V, H, W, 3] float32 base colour, sRGB-encoded, in [0, 1].
        roughness: [V, H, W, 1] float32 perceptual roughness in [0, 1].
        metallic: [V, H, W, 1] float32 metalness in [0, 1].
        valid: [V, H, W] bool, where the maps hold a target.
        K: [V, 3, 3] float32 pixel intrinsics (pixel centres at +0.5).
        w2c: [V, 4, 4] float32 world-to-camera (OpenCV axes).
    """

    albedo: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    valid: np.ndarray
    K: np.ndarray
    w2c: np.ndarray

    def __post_init__(self) -> None:
        v, h, w = self.valid.shape
        expected = {"albedo": (v, h, w, 3), "roughness": (v, h, w, 1), "metallic": (v, h, w, 1),
                    "K": (v, 3, 3), "w2c": (v, 4, 4)}
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"StagedTargets.{name} must have shape {shape}, got "
                                 f"{tuple(getattr(self, name).shape)}")
        if self.valid.dtype != bool:
            raise ValueError(f"StagedTargets.valid must be bool, got {self.valid.dtype}")
        for name in ("albedo", "roughness", "metallic"):
            if not np.isfinite(getattr(self, name)).all():
                raise ValueError(f"StagedTargets.{name} holds NaN/Inf values")

    @property
    def num_views(self) -> int:
        return self.valid.shape[0]

    @property
    def height(self) -> int:
        return self.valid.shape[1]

    @property
    def width(self) -> int:
        return self.valid.shape[2]

    def tensors(self, device=None) -> dict[str, torch.Tensor]:
        """Every field as a torch tensor (float32, valid bool) on ``device``."""
        return {f.name: torch.as_tensor(getattr(self, f.name), device=device) for f in fields(self)}

    def subset(self, views) -> "StagedTargets":
        """Targets of the selected views (index array or list)."""
        return StagedTargets(**{f.name: getattr(self, f.name)[views] for f in fields(self)})


def fill_nearest(values: np.ndarray, valid: np.ndarray, region: np.ndarray) -> np.ndarray:
    """[H, W, C] values with pixels of ``region & ~valid`` set from the nearest valid pixel."""
    if not valid.any():
        return values
    _, (rows, cols) = ndimage.distance_transform_edt(~valid, return_indices=True)
    filled = values[rows, cols]
    return np.where((region & ~valid)[..., None], filled, values)


def stage_targets(points: PointCloud, pbr: np.ndarray, renders: LatticeRenders, *,
                  alpha_threshold: Optional[float] = None) -> StagedTargets:
    """Scatters per-point Stage II predictions back into Stage I's lattice views.

    Args:
        points: the Stage I point cloud (``view`` [P] lattice index, ``pixel`` [P, 2] (row, col)).
        pbr: [P, 5] per-point (albedo sRGB RGB, roughness, metallic); clipped to [0, 1].
        renders: Stage I's lattice renders: their cameras become the targets' cameras and their
            size the targets' size (whatever lattice Stage I was configured with).
        alpha_threshold: with a value, the silhouette ``renders.alpha >= alpha_threshold`` is
            filled: invalid pixels inside it take the nearest valid pixel of the same view.
            None: pixels without a point stay invalid.

    Returns:
        :class:`StagedTargets`. Pixels hit by several points hold their mean.

    Raises:
        ValueError: on a shape mismatch, NaN/Inf, or a view / pixel index out of range.
    """
    pbr = np.asarray(pbr, dtype=np.float64)
    if pbr.shape != (len(points), 5):
        raise ValueError(f"pbr must be [P, 5] for P = {len(points)} points, got {pbr.shape}")
    if not np.isfinite(pbr).all():
        raise ValueError(f"pbr holds {int((~np.isfinite(pbr)).sum())} NaN/Inf values")
    height, width = renders.image_size
    known_size = getattr(points, "image_size", None)
    if known_size is not None and tuple(known_size) != (height, width):
        raise ValueError(f"the point cloud indexes {tuple(known_size)} lattice views, but the renders "
                         f"are {height}x{width}: stage the targets with Stage I's own renders")
    maps, valid = scatter_pixel_values(points.view, points.pixel, pbr.clip(0, 1), height=height,
                                       width=width, num_views=renders.num_views)
    if alpha_threshold is not None:
        silhouette = renders.alpha >= alpha_threshold
        maps = np.stack([fill_nearest(maps[v], valid[v], silhouette[v]) for v in range(len(maps))])
        valid = valid | (silhouette & valid.reshape(len(valid), -1).any(1)[:, None, None])
    return StagedTargets(albedo=maps[..., :3], roughness=maps[..., 3:4], metallic=maps[..., 4:5],
                         valid=valid, K=renders.K.astype(np.float32), w2c=renders.w2c.astype(np.float32))


def scene_targets(scene: Scene, split: str = "train") -> StagedTargets:
    """Targets from a scene's ground-truth maps (an oracle Stage II), valid = ``mask.png``.

    Args:
        scene: a canonical scene (``eval.common.layout.read_scene``); its ``train`` split holds the
            32 lattice views of generated scenes.
        split: which views to read.
    """
    maps, valid = read_gt_view_maps(scene, split)
    views = scene.split_views(split)
    return StagedTargets(albedo=maps[..., :3], roughness=maps[..., 3:4], metallic=maps[..., 4:5],
                         valid=valid, K=np.stack([v.K for v in views]).astype(np.float32),
                         w2c=np.stack([v.w2c for v in views]).astype(np.float32))
