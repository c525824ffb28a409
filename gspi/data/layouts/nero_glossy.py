"""NeRO's Glossy Synthetic set (liuyuan-pal/NeRO dataset/database.py GlossySyntheticDatabase)
<-> the canonical layout.

CLI (gspi/cli/data.py):
    gspi-data import.src=data/GlossySynthetic/bell import.format=nero_glossy out=DIR
    gspi-data export.src=DIR/s000_torus_metal export.format=nero_glossy out=NERO_DIR

Layout: a flat object folder with, for k = 0 .. n-1 (n = the number of `*.pkl` files), `<k>.png`
(sRGB image; NeRO reads its RGB), `<k>-camera.pkl` (a pickled [pose, K]: pose = 3x4 OpenCV
world-to-camera [R | t], K = 3x3 pixel intrinsics with pixel centres at +0.5, as NeRO's
renderer casts rays) and `<k>-depth.png` (16-bit, depth = v / 65535 x 15, foreground where
depth < 14.5). NeRO scores this set on geometry only (Chamfer distance, eval_synthetic_shape.py);
it holds no albedo, roughness, metallic, normals or relit images: scene.json `gt_channels` = []
and gspi-eval refuses it naming what is missing. Its use in gspi is as input (gspi-run).

Views: every view goes to `train`, unless `import.split` names NeRO's split pickle
(configs/synthetic_split_128.pkl: [test ids, train ids]), or the folder holds `gspi.json`
(written by the export: the scene's name, environments and view ids per split).
Conversions: rgb.exr = sRGB-decoded RGB x mask, mask from depth, depth.exr = depth x mask.

Pickles are read with an unpickler that accepts numpy arrays, lists and tuples only (a
pickle can run code; a dataset file must not).
"""
from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np

from eval.common.atomic import write_json_atomic
from eval.common.imageio import read_png, write_png
from eval.common.layout import LayoutError, Scene, View, check_name, read_json_object, read_scene, \
    read_view_file, write_scene_json, write_view_file
from gspi.data.layouts.nerf_synthetic import linear_from_rgba, rgba_from_linear, write_input_view

DEPTH_MAX = 15.0   # depth = v / 65535 * 15 (GlossySyntheticDatabase.get_depth)
DEPTH_BACKGROUND = 14.5
ALLOWED_GLOBALS = {("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
                   ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "scalar"),
                   ("numpy._core.multiarray", "scalar")}


class _ArrayUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) not in ALLOWED_GLOBALS:
            raise pickle.UnpicklingError(f"{module}.{name} is not allowed in a camera file")
        return super().find_class(module, name)


def read_pickle(path: Path):
    if not path.is_file():
        raise LayoutError(f"{path}: file not found")
    try:
        return _ArrayUnpickler(io.BytesIO(path.read_bytes())).load()
    except Exception as exc:  # any unpickling failure is a bad file, named
        raise LayoutError(f"{path}: not a NeRO camera pickle of numpy arrays ({exc})") from exc


def read_camera(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(K [3, 3], w2c [4, 4]) of a `<k>-camera.pkl`."""
    data = read_pickle(path)
    try:
        pose, K = (np.asarray(x, np.float64) for x in data[:2])
    except (TypeError, ValueError, IndexError) as exc:
        raise LayoutError(f"{path}: expected [pose 3x4, K 3x3] ({exc})") from exc
    if pose.shape != (3, 4) or K.shape != (3, 3) or not (np.isfinite(pose).all() and np.isfinite(K).all()):
        raise LayoutError(f"{path}: expected a finite [pose 3x4, K 3x3], got shapes {pose.shape}, {K.shape}")
    return K, np.vstack([pose, [0.0, 0.0, 0.0, 1.0]])


def _splits(src: Path, n: int, split_file: str | Path | None) -> tuple[dict[str, list[str]], dict]:
    """split -> NeRO image ids, and the gspi.json info (if any)."""
    ids = [str(k) for k in range(n)]
    if (src / "gspi.json").is_file():
        info = read_json_object(src / "gspi.json")
        return {s: [str(i) for i in v] for s, v in info.get("nero_ids", {}).items()}, info
    if split_file is None:
        return {"train": ids}, {}
    data = read_pickle(Path(split_file))
    test, train = ([str(i) for i in part] for part in data[:2])
    return {"train": train, "test": test}, {}


def import_nero_glossy(src: str | Path, out_dir: str | Path, *, name: str | None = None,
                       split: str | Path | None = None) -> Scene:
    """Convert a Glossy Synthetic object folder into `<out_dir>/<name>/` (module docstring).

    Raises:
        LayoutError: no `*-camera.pkl`, or a camera, image or depth file missing or malformed.
    """
    from gspi.data.layouts import refuse_glossy_real

    refuse_glossy_real(Path(src))
    src = Path(src)
    n = len(list(src.glob("*-camera.pkl"))) if src.is_dir() else 0
    if n == 0:
        raise LayoutError(f"{src}: no <k>-camera.pkl files (NeRO Glossy Synthetic layout)")
    splits, info = _splits(src, n, split)
    name = check_name(name or info.get("name") or src.name, "import.name (the imported scene's folder)")
    root, views, size = Path(out_dir) / name, {}, None
    for s, ids in splits.items():
        views[s] = []
        for i, k in enumerate(ids):
            K, w2c = read_camera(src / f"{k}-camera.pkl")
            rgb = read_png(src / f"{k}.png", channels=3)
            depth = read_png(src / f"{k}-depth.png", channels=1) * DEPTH_MAX
            mask = depth < DEPTH_BACKGROUND
            vid = check_name(str(info.get("ids", {}).get(s, ids)[i]), f"{src / 'gspi.json'}: ids.{s}[{i}]")
            vdir = root / s / vid
            write_input_view(vdir, linear_from_rgba(np.concatenate([rgb, mask], -1)), mask)
            write_view_file(vdir, "depth.exr", (depth * mask).astype(np.float32))
            if size is not None and rgb.shape[:2] != size:
                raise LayoutError(f"{src / f'{k}.png'}: size {rgb.shape[:2]} differs from earlier images {size}")
            size = rgb.shape[:2]
            views[s].append(View(vid, s, K, w2c))
    scene = Scene(root=root, name=name, width=size[1], height=size[0], views=views,
                  capture_env=str(info.get("capture_env", "unknown")), relight_envs=[], gt_channels=(),
                  relit_gt="images", extra={"source": {"format": "nero_glossy", "path": str(src)}})
    write_scene_json(scene)
    return scene


def export_nero_glossy(scene_dir: str | Path, out_dir: str | Path) -> Path:
    """Write a canonical scene as a Glossy Synthetic object folder (views numbered over the
    splits in order; `gspi.json` keeps the ids and splits so that the import restores them)."""
    scene = read_scene(scene_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    k, nero_ids, ids = 0, {}, {}
    for s, views in scene.views.items():
        nero_ids[s], ids[s] = [], []
        for v in views:
            vdir = scene.view_dir(s, v.id)
            mask = read_view_file(vdir, "mask.png")
            write_png(out / f"{k}.png", rgba_from_linear(read_view_file(vdir, "rgb.exr"), mask)[..., :3], bits=8)
            depth = read_view_file(vdir, "depth.exr") if (vdir / "depth.exr").is_file() else None
            if depth is None:
                raise LayoutError(f"{vdir / 'depth.exr'}: NeRO's layout needs depth (its mask is depth < 14.5)")
            write_png(out / f"{k}-depth.png", np.where(mask > 0.5, np.clip(depth, 0, DEPTH_MAX), DEPTH_MAX) / DEPTH_MAX,
                      bits=16)
            (out / f"{k}-camera.pkl").write_bytes(pickle.dumps([v.w2c[:3, :4].copy(), v.K.copy()]))
            nero_ids[s].append(str(k))
            ids[s].append(v.id)
            k += 1
    write_json_atomic(out / "gspi.json", {"name": scene.name, "capture_env": scene.capture_env,
                                          "nero_ids": nero_ids, "ids": ids})
    return out
