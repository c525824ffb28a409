"""GaussianShader (Asparagus15/GaussianShader @ de77861) adapter.

Input: the Blender loader (`transforms_*.json` + RGBA PNG). Square images only: the loader
swaps FovX and FovY in its `camera_angle_x` branch, harmless only when W = H.
Output read (render.py): `<model>/<split>/ours_<iter>/{diffuse_color,roughness}/{k:05d}.png`;
split `test`, or `train` (the lattice views: the recipe's render.py renders both, `shuffle=False`).

* albedo: GaussianShader has no albedo; the closest proxy is `diffuse_color/`, the view-
  independent diffuse radiance sigmoid(kd - ln 3) (lighting baked in), in display space (the
  image is the plain sum of terms compared with sRGB targets), so it is taken as sRGB-encoded
  as is. `albedo_source: diffuse` takes the raw parameter kd instead (not recommended).
* roughness: channel 0 of the grey `roughness/` map (sigmoid, linear).
* metallic: not modelled: absent.
Maps are alpha-blended over the training background (white with `-w`); inside the mask the
opacity is ~1, outside values are left as they are (metrics are masked).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.adapter import Adapter, AdapterError, find_iteration_dir, grey_channel, option, \
    read_output_png
from eval.common.layout import Scene, View, read_scene

ALBEDO_SOURCES = ("diffuse_color", "diffuse")


class GaussianShaderAdapter(Adapter):
    name = "gaussianshader"

    def export(self, scene_dir, out_dir, cfg) -> Path:
        scene = read_scene(scene_dir)
        if scene.width != scene.height:
            raise AdapterError(f"{scene.root}: GaussianShader needs square images (its loader "
                               f"swaps FovX/FovY), scene is {scene.width}x{scene.height}")
        return super().export(scene_dir, out_dir, cfg)

    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> Path:
        """`<src>/<split>/ours_<iter>` (30000 with the README recipe)."""
        return find_iteration_dir(src / split, "ours_", cfg.get("iteration"),
                                  "GaussianShader render.py output")

    def read_view(self, outputs: Path, index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        name = f"{index:05d}.png"
        source = option(cfg, "albedo_source", ALBEDO_SOURCES)
        albedo = read_output_png(outputs / source / name, f"GaussianShader {source} (display "
                                 f"space) of {view.split} view {index} ({view.id})")
        rough_path = outputs / "roughness" / name
        rough = read_output_png(rough_path, f"GaussianShader roughness of {view.split} view {index} "
                                            f"({view.id})")
        return {"albedo": albedo[..., :3], "roughness": grey_channel(rough, rough_path)}
