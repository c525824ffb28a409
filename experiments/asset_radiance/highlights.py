"""How much of a scene's captured highlights a 2DGS asset keeps (issue 24, "where the signal is lost").

Stage II's prior reads the asset's lattice renders (``stage2.encoders.lattice_images_srgb``:
clamped to [0, 1], sRGB-encoded). On a metal scene the captured lattice views carry the metal
signal in their highlights; an asset whose photometric fit cannot hold them (Stage 0 fits
display values with L1, whose per-point optimum over views is the median: a highlight seen in
few views is dropped) hands the prior a dull object. This module compares the radiance of the
asset's lattice renders with the scene's own lattice views inside the GT mask.

    python -m experiments.asset_radiance.highlights ASSET.ply SCENE_DIR        # prints one JSON line
"""
from __future__ import annotations

import json
import sys

import numpy as np
import torch

QUANTILES = (0.5, 0.9, 0.99)


def radiance_stats(images: np.ndarray, mask: np.ndarray) -> dict:
    """Statistics of linear radiance [V, H, W, 3] over the `mask` [V, H, W] pixels: mean,
    quantiles of the channel values, maximum, the fraction of pixels with a channel above 1
    (what the encoder's clamp saturates), and the mean of the encoder's input
    (clamp to [0, 1] + sRGB)."""
    from eval.common.colorspace import linear_to_srgb

    values = images[mask]
    encoded = linear_to_srgb(torch.from_numpy(np.clip(values, 0.0, 1.0))).numpy()
    return {"mean": float(values.mean()), **{f"q{round(q * 100)}": float(np.quantile(values, q)) for q in QUANTILES},
            "max": float(values.max()), "frac_above_1": float((values.max(-1) > 1.0).mean()),
            "encoder_mean": float(encoded.mean())}


def compare(asset_path: str, scene_dir: str) -> dict:
    """{"captured": stats of the scene's lattice (train) views, "asset": stats of the asset's
    lattice renders at the scene's size}, both inside the GT masks."""
    from eval.common.layout import read_scene, read_view_file
    from gspi.gaussians.lattice_render import render_lattice
    from gspi.gaussians.ply import read_asset_ply

    scene = read_scene(scene_dir)
    views = scene.split_views("train")
    captured = np.stack([read_view_file(scene.view_dir("train", v.id), "rgb.exr") for v in views])
    mask = np.stack([read_view_file(scene.view_dir("train", v.id), "mask.png")[..., 0] > 0.5 for v in views])
    gaussians, _ = read_asset_ply(asset_path)
    rendered = render_lattice(gaussians, image_size=(scene.height, scene.width)).rgb
    return {"scene": scene.name, "asset": str(asset_path), "captured": radiance_stats(captured, mask),
            "rendered": radiance_stats(rendered, mask)}


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        raise SystemExit("usage: python -m experiments.asset_radiance.highlights ASSET.ply SCENE_DIR")
    torch.set_num_threads(1)
    print(json.dumps(compare(*argv)))


if __name__ == "__main__":
    main()
