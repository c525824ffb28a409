"""GS-IR (lzhnb/GS-IR @ e5a030b) adapter: Blender-style input, `pbr/*_brdf.png` panels out.

Output read (render.py with `--pbr`): `<model>/<split>/ours_None/pbr/{k:05d}_brdf.png`, 8-bit RGB
of width 3W = [albedo | roughness x3 | metallic x3] (the iteration tag is the literal `None`);
split `test`, or `train` (the lattice views: render.py renders them when `render_lattice: true`
drops `--skip_train`; `Scene(shuffle=False)` keeps the exported frame order).

* albedo: with `gamma: true` (the TensoIR object recipe, `--gamma`) GS-IR shades in linear
  space and applies the sRGB OETF afterwards, so the saved albedo is linear: it is sRGB-encoded
  here. With `gamma: false` it lives in the display space of the input images and is kept as is.
* roughness: channel 0 of the middle panel; `roughness_remap: true` applies the remapping GS-IR
  trains with, 0.04 + 0.96 r (train.py), which render.py does not apply before saving.
* metallic: the right panel only with `metallic: true` (trained with `--metallic`); without it
  the parameter never enters shading, so the channel is left absent.
Maps are alpha-premultiplied (0 on the background) and no opacity is saved; interior pixels of
the mask are unaffected, so values are taken as they are.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.adapter import Adapter, find_iteration_dir, grey_channel, option, \
    read_output_png, skip_train_flag, split_panels, srgb_encode
from eval.common.layout import Scene, View

ROUGHNESS_MIN = 0.04  # train.py shades with 0.04 + 0.96 * r


def remap_roughness(r: np.ndarray) -> np.ndarray:
    """GS-IR's training-time roughness remapping r -> 0.04 + 0.96 r (r in [0, 1])."""
    return ROUGHNESS_MIN + (1.0 - ROUGHNESS_MIN) * r


class GsIrAdapter(Adapter):
    name = "gs_ir"

    def template_fields(self, cfg: dict) -> dict[str, str]:
        return {"gamma_flag": "--gamma" if option(cfg, "gamma", (True, False)) else "",
                "metallic_flag": "--metallic" if option(cfg, "metallic", (True, False)) else "",
                "skip_train_flag": skip_train_flag(cfg)}

    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> Path:
        """`<src>/<split>/ours_<iteration>/pbr` (iteration "None" for GS-IR's render.py)."""
        hint = " and without --skip_train (method.render_lattice=true)" if split == "train" else ""
        split_dir = find_iteration_dir(src / split, "ours_", cfg.get("iteration"),
                                       f"GS-IR render.py output, run with --pbr{hint}")
        return split_dir / "pbr"

    def read_view(self, outputs: Path, index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        path = outputs / f"{index:05d}_brdf.png"
        image = read_output_png(path, f"GS-IR albedo|roughness|metallic panels of test view "
                                      f"{index} ({view.id})")
        albedo, rough, metal = split_panels(image, 3, path)
        maps = {"albedo": srgb_encode(albedo) if option(cfg, "gamma", (True, False)) else albedo}
        roughness = grey_channel(rough, path)
        maps["roughness"] = remap_roughness(roughness) if cfg.get("roughness_remap", True) \
            else roughness
        if option(cfg, "metallic", (True, False)):
            maps["metallic"] = grey_channel(metal, path)
        return maps
