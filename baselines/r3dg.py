"""R3DG / Relightable 3D Gaussians (NJU-3DV/Relightable3DGaussian @ a102f14) adapter.

Input: the Blender loader (`transforms_*.json` + RGBA PNG); the data path must not contain
`stanford_orb` or `Synthetic4Relight`, which switch the loader.
Output read (eval_nvs.py): `<model>/neilf/<split>/ours_<N>/{base_color,roughness}/{k:05d}.png`
(`src` may be `<model>` or `<model>/neilf`; N = the checkpoint's iteration, highest by default);
split `test`, or `train` (the lattice views: the recipe's eval_nvs.py renders both, `shuffle=False`).

* albedo: `base_color/` is the sRGB OETF of the linear base colour: already the canonical
  encoding, taken as is.
* roughness: channel 0 of the grey `roughness/` map (linear, in [0.09, 0.99] by construction).
* metallic: not modelled (fixed F0 = 0.04): absent.
Maps are divided by the rendered opacity (not premultiplied); no opacity map is saved.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.adapter import Adapter, find_iteration_dir, first_existing, grey_channel, \
    read_output_png
from eval.common.layout import Scene, View


class R3dgAdapter(Adapter):
    name = "r3dg"
    forbidden_path_words = ("stanford_orb", "Synthetic4Relight")

    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> Path:
        """`<src>[/neilf]/<split>/ours_<N>`."""
        root = first_existing([src / "neilf" / split, src / split],
                              "R3DG eval_nvs.py output of the neilf stage")
        return find_iteration_dir(root, "ours_", cfg.get("iteration"), "R3DG eval_nvs.py output")

    def read_view(self, outputs: Path, index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        name = f"{index:05d}.png"
        albedo = read_output_png(outputs / "base_color" / name,
                                 f"R3DG base colour (sRGB) of {view.split} view {index} ({view.id})")
        rough_path = outputs / "roughness" / name
        rough = read_output_png(rough_path, f"R3DG roughness of {view.split} view {index} ({view.id})")
        return {"albedo": albedo[..., :3], "roughness": grey_channel(rough, rough_path)}
