"""The one reader of a canonical scene's ground-truth material maps, view by view.

Stage II's point-cloud measure (Table 2), its generated-cloud measure and Stage III's oracle
targets all read the same files (docs/FORMAT.md): ``albedo.png`` (sRGB-encoded, as stored),
``roughness.png``, ``metallic.png`` and ``mask.png`` of every view of a split, in the order of
``scene.json`` (for ``train``, the lattice order).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eval.common.layout import Scene, read_scene, read_view_file

PBR_FILES = ("albedo.png", "roughness.png", "metallic.png")


def read_gt_view_maps(scene: Scene | str | Path, split: str = "train") -> tuple[np.ndarray, np.ndarray]:
    """GT maps of every view of ``split``.

    Returns:
        maps [V, H, W, 5] float32 (albedo sRGB-encoded RGB, roughness, metallic) and
        mask [V, H, W] bool (``mask.png`` > 0.5).
    """
    scene = scene if isinstance(scene, Scene) else read_scene(scene)
    maps, masks = [], []
    for view in scene.split_views(split):
        vdir = scene.view_dir(split, view.id)
        maps.append(np.concatenate([read_view_file(vdir, f) for f in PBR_FILES], axis=-1))
        masks.append(read_view_file(vdir, "mask.png")[..., 0] > 0.5)
    return np.stack(maps).astype(np.float32), np.stack(masks)
