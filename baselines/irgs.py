"""IRGS (fudan-zvg/IRGS @ 1461869) adapter.

Input: the Blender loader (`transforms_*.json` + RGBA PNG); the data path must not contain
`TensoIR`, `Synthetic4Relight` or `blender_LDR`, which switch the loader.
Output read (render.py without `--no_save`): `<model>/irgs/<split>/ours_<iter>/<key>/{k:05d}.png`
(`src` may be `<model>` or `<model>/irgs`; iter = the highest by default, 20000 here); split
`test`, or `train` (the lattice views: the recipe's render.py renders both, `shuffle=False`).

* albedo: `albedo_source: base_color_linear` (default) holds the linear base colour: it is
  sRGB-encoded here; `base_color` holds the same already sRGB-encoded (taken as is).
* roughness: channel 0 of the grey `roughness/` map (linear).
* metallic: a PLY attribute that never enters shading (F0 = 0.04): absent.
Every map is multiplied by the rendered alpha and the GT mask; interior pixels are unaffected,
edge pixels carry the alpha weighting. The rendered alpha (`rend_alpha/`, saved x GT mask as
well) is imported as the view's `alpha.png`, so `eval.unpremultiply=true` can divide it out;
without that option the maps are scored as saved.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.adapter import Adapter, find_iteration_dir, first_existing, grey_channel, option, \
    read_output_png, srgb_encode
from eval.common.layout import Scene, View

ALBEDO_SOURCES = ("base_color_linear", "base_color")


class IrgsAdapter(Adapter):
    name = "irgs"
    forbidden_path_words = ("TensoIR", "Synthetic4Relight", "blender_LDR")

    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> Path:
        """`<src>[/irgs]/<split>/ours_<iter>`."""
        root = first_existing([src / "irgs" / split, src / split],
                              "IRGS render.py output of the irgs stage")
        return find_iteration_dir(root, "ours_", cfg.get("iteration"), "IRGS render.py output")

    def read_view(self, outputs: Path, index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        name = f"{index:05d}.png"
        source = option(cfg, "albedo_source", ALBEDO_SOURCES)
        albedo = read_output_png(outputs / source / name,
                                 f"IRGS {source} of {view.split} view {index} ({view.id})")[..., :3]
        rough_path = outputs / "roughness" / name
        rough = read_output_png(rough_path, f"IRGS roughness of {view.split} view {index} ({view.id})")
        maps = {"albedo": srgb_encode(albedo) if source == "base_color_linear" else albedo,
                "roughness": grey_channel(rough, rough_path)}
        alpha_path = outputs / "rend_alpha" / name
        if alpha_path.is_file():  # render.py saves it beside the maps (x GT mask, like them)
            maps["alpha"] = grey_channel(read_output_png(alpha_path, f"IRGS rendered opacity of "
                                                         f"{view.split} view {index} ({view.id})"), alpha_path)
        return maps
