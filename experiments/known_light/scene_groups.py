"""The held-out pool's scene groups (parts pool [224:256], by what each scene is made of: its
scene.json's generator) and the IoU mean over a group, shared by the study's tables."""
from __future__ import annotations

import numpy as np

# scenes of the held-out pool (parts pool [224:256]) by what they are made of (their scene.json's
# generator): the `metal` class and the objects of several parts, each its own material
METAL_SCENES = tuple(f"p{i:04d}" for i in range(224, 231))
PARTS_SCENES = tuple(f"p{i:04d}" for i in (224, 225, 226, 229, 230, 231, 233, 235, 238, 242, 243, 245, 246,
                                             247, 249, 250, 252, 253))
# the held-out scenes with no metallic point at all in their GT (gt_points.npz): exact zeros score up to the
# protocol's 60 dB cap there, so these 6 scenes weigh on the mean metallic PSNR as much as the other 26
NO_METAL_SCENES = ("p0239", "p0240", "p0241", "p0244", "p0254", "p0255")


def iou_mean(ious: dict, prefixes: tuple[str, ...]) -> float:
    vals = [v for k, v in ious.items() if k[:5] in prefixes and v is not None]
    return float(np.mean(vals)) if vals else float("nan")
