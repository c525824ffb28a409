"""External systems' outputs written in code: the baselines' image helpers.

Fixture folders in a system's real output layout are written from the known canonical maps of a
tiny sphere scene as 8-bit PNGs like torchvision's save_image (round half up, grey maps as 3 equal
channels); the expected maps are computed with the sRGB formulas written out here on purpose (not
eval.common.colorspace). Used by tests/test_baselines_adapters.py and the tests that import a system's
outputs (export, runtime, lattice views, gspi-run external rows).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from eval.common.layout import read_view_file


def srgb_oetf(x):  # IEC 61966-2-1, written out here on purpose (not eval.common.colorspace)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_eotf(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def q8(x):
    """What torchvision's save_image stores: clamp, x * 255 + 0.5, floor; read back / 255."""
    return np.floor(np.clip(x, 0.0, 1.0) * 255 + 0.5) / 255


def save_image(path: Path, x: np.ndarray) -> None:
    """torchvision.utils.save_image of a [C, H, W] tensor in [0, 1] (here HxW or HxWx3)."""
    x = np.asarray(x, np.float64)
    if x.ndim == 2:
        x = np.repeat(x[..., None], 3, -1)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.floor(np.clip(x, 0, 1) * 255 + 0.5).astype(np.uint8), "RGB").save(path)


def gt_maps(scene):
    """Per test view: albedo (sRGB-encoded), roughness, metallic as stored in the scene."""
    out = []
    for v in scene.split_views("test"):
        d = scene.view_dir("test", v.id)
        out.append({"albedo": read_view_file(d, "albedo.png").astype(np.float64),
                    "roughness": read_view_file(d, "roughness.png")[..., 0].astype(np.float64),
                    "metallic": read_view_file(d, "metallic.png")[..., 0].astype(np.float64)})
    return out


# GS-IR's test/ours_<iteration>/pbr/: <k>_brdf.png = albedo | (roughness - 0.04) / 0.96 | metallic
def write_gs_ir(root: Path, maps, *, gamma=True, iteration="None"):
    pbr = root / "test" / f"ours_{iteration}" / "pbr"
    for k, m in enumerate(maps):
        albedo = srgb_eotf(m["albedo"]) if gamma else m["albedo"]
        rough_saved = (m["roughness"] - 0.04) / 0.96
        panels = [albedo] + [np.repeat(x[..., None], 3, -1) for x in (rough_saved, m["metallic"])]
        save_image(pbr / f"{k:05d}_brdf.png", np.concatenate(panels, axis=1))
        save_image(pbr / f"{k:05d}.png", albedo)  # the PBR render, not read
    return root
