"""LumiGauss (joaxkal/lumigauss @ caf34ff) adapter: COLMAP-style input, albedo panels out.

Input (its COLMAP reader; the Blender branch cannot run): `<out>/images/<split>_<id>.png` (8-bit
sRGB RGB, black background), `<out>/masks/<same name>` (8-bit grey, 255 = object), a text model
`<out>/sparse/0/{cameras,images,points3D}.txt` (PINHOLE, one camera per image, the scene's
OpenCV w2c as COLMAP's qvec/tvec) and `<out>/<scene name>_split.csv` (`filename;split`).
COLMAP has no points for a rendered scene: `points3D.txt` holds `init_points` seeded random
points in the cube [-1.3, 1.3]^3, what the Blender loaders of the other systems generate.
Output read (render_simple.py): `<model>/render_<split>/ours_<iter>/renders/<image name>_albedo.png`,
two panels [GT | albedo], named by image (with its extension), so order does not matter; split
`test`, or `train` (the lattice views, rendered when `render_lattice: true` drops `--skip_train`).

* albedo: LumiGauss multiplies albedo by gamma-encoded shading, so the albedo lives in gamma-2.2
  space (`albedo_space: gamma22`): linear = x^2.2, then sRGB-encoded; `srgb` keeps it as is.
* roughness, metallic: not modelled (Lambertian): absent.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from baselines.adapter import Adapter, find_iteration_dir, option, read_output_png, \
    skip_train_flag, split_panels, srgb_encode
from eval.common.colorspace import linear_to_srgb
from eval.common.imageio import write_png
from eval.common.layout import Scene, View, read_scene, read_view_file

ALBEDO_SPACES = ("gamma22", "srgb")
EXPORTED_SPLITS = ("train", "test")
POINT_CUBE = 1.3  # half-size of the random initial point cube (as the Blender loaders)


def image_name(view: View) -> str:
    """File name of a view in `images/` (and the stem of its LumiGauss outputs)."""
    return f"{view.split}_{view.id}.png"


def colmap_qvec_tvec(w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV w2c [4, 4] -> COLMAP (qw, qx, qy, qz), t: same camera convention, so no flips."""
    x, y, z, w = Rotation.from_matrix(w2c[:3, :3]).as_quat()
    return np.array([w, x, y, z]), w2c[:3, 3]


def write_colmap_text(scene: Scene, sparse_dir: Path, *, num_points: int, seed: int) -> None:
    """`cameras.txt`, `images.txt`, `points3D.txt` of the train and test views (COLMAP text)."""
    sparse_dir.mkdir(parents=True, exist_ok=True)
    cams, imgs = ["# CAMERA_ID MODEL WIDTH HEIGHT fx fy cx cy"], \
        ["# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then an empty 2D-point line"]
    k = 0
    for split in EXPORTED_SPLITS:
        for view in scene.views.get(split, []):
            k += 1
            fx, fy, cx, cy = view.K[0, 0], view.K[1, 1], view.K[0, 2], view.K[1, 2]
            cams.append(f"{k} PINHOLE {scene.width} {scene.height} "
                        f"{fx:.17g} {fy:.17g} {cx:.17g} {cy:.17g}")
            q, t = colmap_qvec_tvec(view.w2c)
            imgs.append(f"{k} {' '.join(f'{v:.17g}' for v in (*q, *t))} {k} {image_name(view)}")
            imgs.append("")
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-POINT_CUBE, POINT_CUBE, size=(num_points, 3))
    pts = ["# POINT3D_ID X Y Z R G B ERROR"] + [
        f"{i + 1} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} 128 128 128 0" for i, p in enumerate(xyz)]
    for name, lines in (("cameras.txt", cams), ("images.txt", imgs), ("points3D.txt", pts)):
        (sparse_dir / name).write_text("\n".join(lines) + "\n")


class LumiGaussAdapter(Adapter):
    name = "lumigauss"

    def export(self, scene_dir, out_dir, cfg) -> Path:
        """Write images/, masks/, sparse/0/*.txt and <scene>_split.csv (module docstring)."""
        scene, out = read_scene(scene_dir), Path(out_dir)
        rows = []
        for split in EXPORTED_SPLITS:
            for view in scene.views.get(split, []):
                vdir = scene.view_dir(split, view.id)
                rgb = linear_to_srgb(torch.from_numpy(read_view_file(vdir, "rgb.exr"))).numpy()
                write_png(out / "images" / image_name(view), rgb)
                write_png(out / "masks" / image_name(view), read_view_file(vdir, "mask.png"))
                rows.append((image_name(view), split))
        write_colmap_text(scene, out / "sparse" / "0", num_points=int(cfg.get("init_points", 100000)),
                          seed=int(cfg.get("seed", 0)))
        with open(out / f"{scene.name}_split.csv", "w", newline="") as f:
            writer = csv.writer(f, delimiter=";")
            writer.writerow(["filename", "split"])
            writer.writerows(rows)
        return out

    def template_fields(self, cfg: dict) -> dict[str, str]:
        return {"skip_train_flag": skip_train_flag(cfg)}

    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> Path:
        """`<src>/render_<split>/ours_<iter>/renders`."""
        hint = " without --skip_train (method.render_lattice=true)" if split == "train" else ""
        return find_iteration_dir(src / f"render_{split}", "ours_", cfg.get("iteration"),
                                  f"LumiGauss render_simple.py output{hint}") / "renders"

    def read_view(self, outputs: Path, index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        path = outputs / f"{image_name(view)}_albedo.png"
        image = read_output_png(path, f"LumiGauss [GT | albedo] panels of {view.split} view {index} "
                                      f"({view.id})")
        albedo = split_panels(image[..., :3], 2, path)[1]
        if option(cfg, "albedo_space", ALBEDO_SPACES) == "gamma22":
            albedo = srgb_encode(albedo ** 2.2)
        return {"albedo": albedo}
