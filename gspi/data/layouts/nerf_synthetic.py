"""Import NeRF-synthetic style folders into the canonical layout, and export back.

CLI (gspi/cli/data.py):
    gspi-data import.src=path/to/lego out=DIR [import.name=lego] [import.composite=white]
    gspi-data export.src=DIR/s000_torus_metal out=NERF_DIR [export.bits=16]

NeRF-synthetic folder: `transforms_{train,val,test}.json` with `camera_angle_x` (horizontal
FoV, radians) and `frames[*]` = {"file_path": "./train/r_0", "transform_matrix": c2w 4x4};
frames are RGBA PNGs (8- or 16-bit, sRGB, straight alpha); camera convention Blender/OpenGL
(x right, y up, z back). Conversions:

* camera: OpenCV c2w = Blender c2w with columns 1 and 2 negated; w2c = its rigid inverse;
  focal = W / (2 tan(camera_angle_x / 2)) for both axes, cx = W / 2, cy = H / 2;
* image: rgb.exr = srgb_to_linear(rgb) * alpha (composited on black, the layout's background;
  `composite="white"` adds (1 - alpha) for white-background renders); mask = alpha > 0.5;
* optional per-frame maps next to the frame, used when present: `<frame>_albedo.png`
  (sRGB), `<frame>_roughness.png`, `<frame>_metallic.png` (grey, linear),
  `<frame>_normal.exr` (world normals), `<frame>_depth.exr` (OpenCV camera z);
* optional `gspi` key in the json ({"name", "capture_env", "relight_envs"}) and an `envmaps/`
  folder restore the scene's environments (written by `export_nerf_synthetic`).

Export writes rgb as clamp + sRGB (8-bit by default, as NeRF-synthetic; 16 with `bits=16`),
alpha = mask, and the maps above. A round trip keeps cameras (to float rounding), the mask
and the material/normal/depth maps exactly, and rgb within the PNG quantisation inside the
mask (HDR values above 1 are clamped; the anti-aliased fringe outside the mask is dropped).
"""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import png  # pypng: 16-bit RGBA
import torch

from eval.common.atomic import write_json_atomic
from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.common.imageio import read_exr, read_png
from eval.common.layout import SPLITS, LayoutError, Scene, View, check_name, read_scene, read_view_file, \
    write_material, write_scene_json, write_view_file

BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])  # right-multiply a c2w: negate columns 1, 2
MAP_SUFFIXES = {"albedo.png": "_albedo.png", "roughness.png": "_roughness.png",
                "metallic.png": "_metallic.png", "normal.exr": "_normal.exr",
                "depth.exr": "_depth.exr"}


def rigid_inverse(m: np.ndarray) -> np.ndarray:
    """Inverse of a [4, 4] rigid transform (R, t) -> (R^T, -R^T t)."""
    out = np.eye(4)
    out[:3, :3] = m[:3, :3].T
    out[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return out


def blender_c2w_to_opencv_w2c(c2w_blender: np.ndarray) -> np.ndarray:
    return rigid_inverse(np.asarray(c2w_blender, dtype=np.float64) @ BLENDER_TO_OPENCV)


def opencv_w2c_to_blender_c2w(w2c: np.ndarray) -> np.ndarray:
    return rigid_inverse(np.asarray(w2c, dtype=np.float64)) @ BLENDER_TO_OPENCV


def intrinsics_from_angle_x(camera_angle_x: float, width: int, height: int) -> np.ndarray:
    focal = width / (2.0 * math.tan(camera_angle_x / 2.0))
    return np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])


def read_rgba(path: Path) -> np.ndarray:
    """[H, W, 4] float32 in [0, 1] (alpha = 1 when the PNG has none)."""
    if not path.is_file():
        raise LayoutError(f"{path}: frame not found")
    width, height, rows, info = png.Reader(filename=str(path)).asRGBA()
    arr = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows]).reshape(height, width, 4)
    return arr.astype(np.float32) / float(2 ** info["bitdepth"] - 1)


def write_rgba(path: Path, rgba: np.ndarray, *, bits: int = 8) -> None:
    maxval = 2 ** bits - 1
    q = np.round(np.clip(rgba, 0.0, 1.0) * maxval).astype(np.uint16 if bits == 16 else np.uint8)
    h, w = q.shape[:2]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        png.Writer(w, h, alpha=True, greyscale=False, bitdepth=bits).write(f, q.reshape(h, -1))


def _frame_path(src: Path, file_path: str) -> Path:
    p = src / file_path
    return p if p.suffix.lower() == ".png" else p.with_name(p.name + ".png")


def linear_from_rgba(rgba: np.ndarray) -> np.ndarray:
    """[H, W, 3] linear radiance of an sRGB straight-alpha frame, composited on black."""
    return srgb_to_linear(torch.from_numpy(np.ascontiguousarray(rgba[..., :3]))).numpy() * rgba[..., 3:]


def rgba_from_linear(rgb_linear: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """[H, W, 4] sRGB frame (clamped to [0, 1]) with ``alpha`` [H, W, 1]: what exporters write."""
    return np.concatenate([linear_to_srgb(torch.from_numpy(rgb_linear)).numpy(), alpha], -1)


def write_input_view(view_dir: Path, rgb_linear: np.ndarray, mask: np.ndarray) -> None:
    """A view's input image (rgb.exr, its rgb.png preview) and mask.png (``mask`` [H, W, 1] bool)."""
    write_view_file(view_dir, "rgb.exr", rgb_linear)
    write_view_file(view_dir, "rgb.png", linear_to_srgb(torch.from_numpy(rgb_linear)).numpy())
    write_view_file(view_dir, "mask.png", mask.astype(np.float32))


def _import_frame(frame_png: Path, view_dir: Path, composite: str) -> tuple[int, int]:
    rgba = read_rgba(frame_png)
    alpha = rgba[..., 3:]
    rgb = linear_from_rgba(rgba)
    if composite == "white":
        rgb = rgb + (1.0 - alpha)
    elif composite != "black":
        raise ValueError(f"unknown composite {composite!r}; allowed: black, white")
    write_input_view(view_dir, rgb, alpha > 0.5)
    stem = frame_png.with_suffix("")
    for name, suffix in MAP_SUFFIXES.items():
        extra = stem.with_name(stem.name + suffix)
        if not extra.is_file():
            continue
        if name.endswith(".exr"):
            write_view_file(view_dir, name, read_exr(extra))
        else:
            channel = name[:-4]
            write_material(view_dir, channel, read_png(extra, channels=3 if channel == "albedo"
                                                        else 1))
    return rgba.shape[0], rgba.shape[1]


def import_nerf_synthetic(src: str | Path, out_dir: str | Path, *, name: str | None = None,
                          composite: str = "black") -> Scene:
    """Convert a NeRF-synthetic folder into `<out_dir>/<name>/` (see module docstring)."""
    src = Path(src)
    files = {s: src / f"transforms_{s}.json" for s in SPLITS}
    files = {s: p for s, p in files.items() if p.is_file()}
    if not files:
        raise LayoutError(f"{src}: no transforms_{{train,val,test}}.json found")
    meta = {s: json.loads(p.read_text()) for s, p in files.items()}
    info = next((m["gspi"] for m in meta.values() if "gspi" in m), {})
    name = check_name(name or info.get("name") or src.name, "import.name (the imported scene's folder)")
    root = Path(out_dir) / name
    views: dict[str, list[View]] = {}
    size = None
    for split, m in meta.items():
        views[split] = []
        for i, frame in enumerate(m["frames"]):
            frame_png = _frame_path(src, frame["file_path"])
            vid = frame_png.stem
            hw = _import_frame(frame_png, root / split / vid, composite)
            if size is not None and hw != size:
                raise LayoutError(f"{frame_png}: size {hw} differs from earlier frames {size}")
            size = hw
            K = intrinsics_from_angle_x(float(m["camera_angle_x"]), hw[1], hw[0])
            views[split].append(View(vid, split, K, blender_c2w_to_opencv_w2c(
                np.asarray(frame["transform_matrix"], dtype=np.float64))))
    scene = Scene(root=root, name=name, width=size[1], height=size[0], views=views,
                  capture_env=str(info.get("capture_env", "unknown")),
                  relight_envs=[str(e) for e in info.get("relight_envs", [])],
                  extra={"source": {"format": "nerf_synthetic", "path": str(src)}})
    if (src / "envmaps").is_dir():
        shutil.copytree(src / "envmaps", root / "envmaps", dirs_exist_ok=True)
    write_scene_json(scene)
    return scene


def check_angle_x_camera(scene: Scene, v: View) -> float:
    """The view's horizontal FoV (radians) if its K is one camera_angle_x can hold (fx = fy,
    centred principal point), else a LayoutError naming the scene and view."""
    fx, fy, cx, cy = v.K[0, 0], v.K[1, 1], v.K[0, 2], v.K[1, 2]
    if not (math.isclose(fx, fy, rel_tol=1e-9) and math.isclose(cx, scene.width / 2)
            and math.isclose(cy, scene.height / 2)):
        raise LayoutError(f"{scene.root}: view {v.split}/{v.id} has K {v.K.tolist()}, "
                          "not representable by camera_angle_x")
    return 2.0 * math.atan(scene.width / (2.0 * fx))


def export_nerf_synthetic(scene_dir: str | Path, out_dir: str | Path, *, bits: int = 8) -> Path:
    """Write a canonical scene as a NeRF-synthetic folder (see module docstring).

    Raises:
        LayoutError: if a camera is not NeRF-synthetic compatible (fx != fy, off-centre).
    """
    scene = read_scene(scene_dir)
    out = Path(out_dir)
    for split, views in scene.views.items():
        frames, angle = [], None
        for v in views:
            a = check_angle_x_camera(scene, v)
            if angle is not None and not math.isclose(a, angle, rel_tol=1e-12):
                raise LayoutError(f"{scene.root}: split {split} mixes fields of view")
            angle = a
            vdir = scene.view_dir(split, v.id)
            write_rgba(out / split / f"{v.id}.png", rgba_from_linear(read_view_file(vdir, "rgb.exr"),
                                                                  read_view_file(vdir, "mask.png")), bits=bits)
            for name, suffix in MAP_SUFFIXES.items():
                if (vdir / name).is_file():
                    shutil.copyfile(vdir / name, out / split / f"{v.id}{suffix}")
            frames.append({"file_path": f"./{split}/{v.id}",
                           "transform_matrix": opencv_w2c_to_blender_c2w(v.w2c).tolist()})
        data = {"camera_angle_x": angle, "frames": frames,
                "gspi": {"name": scene.name, "capture_env": scene.capture_env,
                         "relight_envs": scene.relight_envs}}
        write_json_atomic(out / f"transforms_{split}.json", data)
    if (scene.root / "envmaps").is_dir():
        shutil.copytree(scene.root / "envmaps", out / "envmaps", dirs_exist_ok=True)
    return out
