"""Input views of a canonical scene (docs/FORMAT.md) as tensors for the reconstruction."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from eval.common.layout import LayoutError, Scene, read_scene, read_view_file

INPUT_FILES = ("rgb.exr", "mask.png")


class ReconInputError(LayoutError):
    """A scene folder lacks what the reconstruction reads; the message names the file(s)."""


@dataclass
class SceneViews:
    """The views of one split, stacked.

    Attributes:
        ids: view ids in the scene's order.
        images: [V, H, W, 3] float32 linear HDR radiance (``rgb.exr``), black background.
        masks: [V, H, W] bool foreground (``mask.png > 0.5``).
        viewmats: [V, 4, 4] float32 world-to-camera (OpenCV).
        Ks: [V, 3, 3] float32 pixel intrinsics.
    """

    ids: list[str]
    images: Tensor
    masks: Tensor
    viewmats: Tensor
    Ks: Tensor

    @property
    def num_views(self) -> int:
        return len(self.ids)

    @property
    def height(self) -> int:
        return self.images.shape[1]

    @property
    def width(self) -> int:
        return self.images.shape[2]

    def select(self, keep: Tensor) -> "SceneViews":
        """The views where ``keep`` [V] bool is true."""
        idx = torch.nonzero(keep.cpu())[:, 0]
        return SceneViews([self.ids[int(i)] for i in idx], self.images[keep], self.masks[keep],
                          self.viewmats[keep], self.Ks[keep])

    def to(self, device) -> "SceneViews":
        return SceneViews(self.ids, self.images.to(device), self.masks.to(device),
                          self.viewmats.to(device), self.Ks.to(device))


def check_scene_files(scene: Scene, split: str, files: tuple[str, ...] = INPUT_FILES) -> None:
    """Raises :class:`ReconInputError` naming every missing per-view file (first 5 listed)."""
    views = scene.split_views(split)
    if not views:
        raise ReconInputError(f"{scene.root / 'scene.json'}: split {split!r} has no views")
    missing = [scene.view_dir(split, v.id) / name for v in views for name in files
               if not (scene.view_dir(split, v.id) / name).is_file()]
    if missing:
        more = f" (and {len(missing) - 5} more)" if len(missing) > 5 else ""
        listed = ", ".join(str(p) for p in missing[:5])
        raise ReconInputError(f"scene {scene.root}: missing input file(s) {listed}{more}")


def load_scene_views(scene_dir: str | Path | Scene, split: str = "train") -> SceneViews:
    """Reads ``rgb.exr`` and ``mask.png`` of every view of ``split``.

    Raises:
        ReconInputError: scene.json missing or invalid, or a view lacks one of the files.
    """
    if isinstance(scene_dir, Scene):
        scene = scene_dir
    else:
        root = Path(scene_dir)
        if not (root / "scene.json").is_file():
            raise ReconInputError(f"{root / 'scene.json'}: file not found (not a canonical scene folder)")
        scene = read_scene(root)
    check_scene_files(scene, split)
    views = scene.split_views(split)
    images, masks = [], []
    for v in views:
        d = scene.view_dir(split, v.id)
        rgb = read_view_file(d, "rgb.exr")
        mask = read_view_file(d, "mask.png")[..., 0] > 0.5
        if rgb.shape[:2] != (scene.height, scene.width) or mask.shape != rgb.shape[:2]:
            raise ReconInputError(f"{d}: image size {rgb.shape[:2]} / mask {mask.shape} != scene.json "
                                  f"{(scene.height, scene.width)}")
        images.append(rgb)
        masks.append(mask)
    f32 = lambda a: torch.from_numpy(np.ascontiguousarray(np.stack(a), dtype=np.float32))  # noqa: E731
    return SceneViews(
        ids=[v.id for v in views],
        images=f32(images),
        masks=torch.from_numpy(np.stack(masks)),
        viewmats=f32([v.w2c for v in views]),
        Ks=f32([v.K for v in views]),
    )
