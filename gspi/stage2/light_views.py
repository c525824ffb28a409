"""The lattice views as observations of each point, for the light estimate and the material
read-out (``gspi.light``): every view that sees a point (``project_to_views``' depth test, the
one the cross-view statistic uses) gives the radiance at its pixel and the direction to its camera.
Which views: the scene's input photos where they were taken at the lattice cameras (they keep the
highlights Stage 0 blurs), else the asset's lattice renders (``lattice_photos``, ``views_to_read``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from gspi.light.observations import PointViews
from gspi.stage2.lattice_cameras import LatticeCameras, project_to_views


def observe_points(images: np.ndarray, depth: np.ndarray, cams: LatticeCameras, xyz: np.ndarray,
                   normal: np.ndarray, *, tol_pixels: float = 2.0, chunk: int = 8192) -> PointViews:
    """PointViews of points ``xyz`` [n, 3] with unit ``normal`` [n, 3] in the linear renders
    ``images`` [V, H, W, 3] with depths ``depth`` [V, H, W] of cameras ``cams``."""
    if images.shape[:3] != depth.shape or images.shape[-1] != 3:
        raise ValueError(f"images {images.shape} must be [V, H, W, 3] over depth {depth.shape} [V, H, W]")
    centers = cams.centers
    points, colours, dirs = [], [], []
    for s in range(0, len(xyz), chunk):
        part = xyz[s:s + chunk]
        row, col, _, visible = project_to_views(cams, depth, part, tol_pixels=tol_pixels)
        view, local = np.nonzero(visible)  # [V, n] -> (view, point) pairs
        order = np.lexsort((view, local))      # rows sorted by point, then view
        view, local = view[order], local[order]
        points.append(local + s)
        colours.append(images[view, row[view, local], col[view, local]])
        dirs.append(centers[view] - part[local])
    return PointViews.from_numpy(np.concatenate(points), np.concatenate(colours), np.concatenate(dirs),
                                 normal, xyz)


LIGHT_VIEWS = ("photos", "renders")  # what the light is read from (stage2.inference.light_views, method.views)


@dataclass(frozen=True)
class LatticePhotos:
    """A scene's input photos taken at the lattice cameras (a benchmark scene's train split)."""

    rgb: np.ndarray  # [V, H, W, 3] linear radiance
    mask: np.ndarray  # [V, H, W] bool foreground


def lattice_photos(scene_dir: Path, renders, *, atol: float = 1e-4) -> tuple[Optional[LatticePhotos], str]:
    """(the scene's train photos, "photos") when they were taken at the renders' cameras, else
    (None, why not). Issue 66, item 3: Stage 0 blurs the highlights that the photos keep, so the
    light is read from the photos with the asset for geometry and visibility; an asset that comes
    without photos at these cameras (a user's own object) is read from its renders."""
    from eval.common.layout import LayoutError, read_scene, read_view_file

    try:
        scene = read_scene(scene_dir)
        views = scene.split_views("train")
    except (LayoutError, FileNotFoundError) as exc:
        return None, f"renders (no photos: {exc})"
    num, height, width = renders.depth.shape
    if len(views) != num or (scene.height, scene.width) != (height, width):
        return None, (f"renders (the {len(views)} photos of {scene.height}x{scene.width} px are not the "
                      f"{num} lattice views of {height}x{width} px)")
    K, w2c = np.stack([v.K for v in views]), np.stack([v.w2c for v in views])
    if not (np.allclose(K, renders.K, atol=atol * max(1.0, float(np.abs(renders.K).max())))
            and np.allclose(w2c, renders.w2c, atol=atol)):
        return None, "renders (the photos were not taken at the lattice cameras)"
    dirs = [scene.view_dir("train", v.id) for v in views]
    rgb = np.stack([read_view_file(d, "rgb.exr", (height, width)) for d in dirs]).astype(np.float32)
    mask = np.stack([read_view_file(d, "mask.png", (height, width))[..., 0] for d in dirs]) > 0.5
    return LatticePhotos(rgb=rgb, mask=mask), "photos"


def views_to_read(renders, photos: Optional[LatticePhotos]) -> tuple[np.ndarray, np.ndarray]:
    """(linear images [V, H, W, 3], depth [V, H, W]) the light and the read-out observe: the
    photos' colours where the photo and the asset both show the object (the asset's depth places
    and tests each point), else the renders'."""
    if photos is None:
        return np.asarray(renders.rgb), np.asarray(renders.depth)
    return photos.rgb, np.where(photos.mask, np.asarray(renders.depth), 0.0).astype(np.float32)
