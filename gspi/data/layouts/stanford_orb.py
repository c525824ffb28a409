"""Stanford-ORB, blender representation (StanfordORB/Stanford-ORB orb/datasets/mymethod.py
BlenderDataset, orb/pipelines/mymethod.py, orb/utils/test.py) <-> the canonical layout.

CLI (gspi/cli/data.py):
    gspi-data import.src=data/blender_HDR/teapot_scene001 import.format=stanford_orb out=DIR
    gspi-data export.src=DIR/s000_torus_metal export.format=stanford_orb out=ORB_DATA

Layout (`data/` of the README): `blender_HDR/<capture>/` (or `blender_LDR/`) holds
`transforms_{train,test}.json` (`camera_angle_x`, frames `file_path` = `test/0000`,
`transform_matrix` = Blender c2w), images `<file_path>.exr` (HDR, linear; `.png` sRGB in
blender_LDR), masks `<dir>_mask/<name>.png`, and `transforms_novel.json`: the test cameras of
the object's other captures aligned to this one (frames with `scene_name` and their own
`camera_angle_x`). `ground_truth/<capture>/` holds per test image `pseudo_gt_albedo/<id>.png`
(sRGB), `surface_normal/<id>.npy` (camera-space, Blender axes), `z_depth/<id>.npy` and
`env_map/<id>.exr` (gspi.data.layouts.orb_envmap). Stanford-ORB scores at 512 px: every
image is area-averaged by the integer factor H // `resolution` (cv2.INTER_AREA), masks are
averaged then thresholded at 0.5, as its loaders do.

Canonical scene of capture A: `train` = A's train frames; `test` = A's test frames (input
photo, mask, pseudo-GT albedo, world normals, depth: per-view `gt_channels` [albedo]) then
one view per frame of transforms_novel.json, id `<B>_<id>` (its photo as rgb.exr and as
`relit_<B>_<id>.exr`, the view's own environment `envmaps/<B>_<id>.exr` in world space,
normals of B's ground truth: per-view `gt_channels` [relight], `relight_envs` [<B>_<id>]).
Stanford-ORB has no roughness or metallic ground truth; `relit_gt` = images. Backgrounds are
photographs: images are multiplied by the mask (the layout's black background).

Export writes `<out>/blender_HDR/<name>/` and `<out>/ground_truth/<name>/` the same way (HDR
EXR frames, 8-bit masks, albedo 8-bit), and each (test view, relit environment) pair as the
test frame of a capture `<name>-<env>` (`<out>/blender_HDR/<name>-<env>/test/<id>.exr`, its
mask, ground truth normals and env map), listed in `transforms_novel.json`: the shape
Stanford-ORB gives relighting (one environment per image).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch

from eval.common.atomic import write_json_atomic
from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.common.imageio import read_exr, read_png, write_exr, write_png
from eval.common.layout import GT_CHANNELS, LayoutError, Scene, View, check_name, read_json_object, read_scene, \
    read_view_file, write_material, write_scene_json, write_view_file
from gspi.data.layouts.orb_envmap import orb_to_world, world_to_orb
from gspi.data.layouts.nerf_synthetic import blender_c2w_to_opencv_w2c, check_angle_x_camera, \
    intrinsics_from_angle_x, opencv_w2c_to_blender_c2w, write_input_view

log = logging.getLogger(__name__)
BENCHMARK_RESOLUTION = 512  # orb/constant.py
EXPORT_ENV_UPSAMPLE = 4  # exported ORB maps have 4x the rows: resampling back to the layout's grid
                         # then lands within a fraction of a texel of where it started


def block_mean(arr: np.ndarray, factor: int, path: Path) -> np.ndarray:
    """Area average by an integer factor (cv2.INTER_AREA for integer factors)."""
    h, w = arr.shape[:2]
    if h % factor or w % factor:
        raise LayoutError(f"{path}: size {h}x{w} is not a multiple of the downsizing factor {factor}")
    return arr.reshape(h // factor, factor, w // factor, factor, *arr.shape[2:]).mean(axis=(1, 3)).astype(np.float32)


class Frames:
    """One capture folder of the blender representation and how its images are read."""

    def __init__(self, folder: Path, resolution: int):
        self.folder, self.resolution = folder, resolution

    def image_path(self, file_path: str) -> Path:
        base = self.folder / file_path
        exr = base.with_name(base.name + ".exr")
        return exr if exr.is_file() else base.with_name(base.name + ".png")

    def mask_path(self, file_path: str) -> Path:
        p = Path(file_path)
        return self.folder / (str(p.parent) + "_mask") / (p.name + ".png")

    def factor(self, size: int) -> int:
        return max(1, size // self.resolution)

    def read(self, file_path: str) -> tuple[np.ndarray, np.ndarray]:
        """(rgb linear x mask [h, w, 3], mask [h, w, 1] bool) at the benchmark resolution."""
        path = self.image_path(file_path)
        if not path.is_file():
            raise LayoutError(f"{path.with_suffix('')}.{{exr,png}}: frame image not found")
        rgb = read_exr(path) if path.suffix == ".exr" else \
            srgb_to_linear(torch.from_numpy(read_png(path, channels=3))).numpy()
        mask = read_png(self.mask_path(file_path), channels=1)
        f = self.factor(rgb.shape[0])
        mask = block_mean(mask, f, self.mask_path(file_path)) > 0.5
        return block_mean(rgb, f, path) * mask, mask


def read_transforms(path: Path) -> dict:
    data = read_json_object(path, what="Stanford-ORB transforms file (the split's cameras)")
    if not isinstance(data.get("frames"), list):
        raise LayoutError(f"{path}: needs a 'frames' list")
    return data


def _camera(frame: dict, angle, size: int, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K, OpenCV w2c, Blender c2w) of a frame at the output size."""
    try:
        c2w = np.asarray(frame["transform_matrix"], np.float64).reshape(4, 4)
        angle = float(frame.get("camera_angle_x", angle))
    except (KeyError, TypeError, ValueError) as exc:
        raise LayoutError(f"{where}: a frame needs transform_matrix (4x4) and camera_angle_x ({exc})") from exc
    return intrinsics_from_angle_x(angle, size, size), blender_c2w_to_opencv_w2c(c2w), c2w


def world_normals(normal_cam_gl: np.ndarray, c2w_gl: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Camera-space (Blender axes) normals -> unit world normals, 0 outside the mask."""
    n = normal_cam_gl @ c2w_gl[:3, :3].T
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return (n * mask).astype(np.float32)


def _write_gt_maps(gt: Path, vid: str, vdir: Path, c2w: np.ndarray, mask: np.ndarray, factor: int,
                   albedo: bool) -> None:
    if albedo:
        write_material(vdir, "albedo", pseudo_gt_albedo_srgb(gt, vid, factor) * mask)
    path = gt / "surface_normal" / f"{vid}.npy"
    write_view_file(vdir, "normal.exr", world_normals(block_mean(_npy(path), factor, path), c2w, mask))
    path = gt / "z_depth" / f"{vid}.npy"
    if path.is_file():
        write_view_file(vdir, "depth.exr", block_mean(_npy(path), factor, path)[..., None] * mask)


def pseudo_gt_albedo_srgb(gt: Path, vid: str, factor: int) -> np.ndarray:
    """The pseudo-GT albedo of test image ``vid``, sRGB-encoded as gspi stores albedo.

    ``pseudo_gt_albedo/<id>.png`` (sRGB) is what ORB's evaluator reads (orb/pipelines/mymethod.py
    47, orb/utils/test.py compute_metrics_material: ``srgb_to_rgb(load_rgb_png(...))``) and is
    preferred. ORB's README lists ``pseudo_gt_albedo/<id>.npy`` instead; no ORB code reads it, so
    it is taken as the layout's other float arrays are (linear values in [0, 1]: the
    evaluator's ``target_rgb``), area-averaged, then encoded. A folder with neither is one line."""
    png, npy = gt / "pseudo_gt_albedo" / f"{vid}.png", gt / "pseudo_gt_albedo" / f"{vid}.npy"
    if png.is_file():
        return block_mean(read_png(png, channels=3), factor, png)
    if not npy.is_file():
        raise LayoutError(f"{png}: pseudo-GT albedo not found (nor {npy.name})")
    linear = _npy(npy)
    if linear.ndim != 3 or linear.shape[-1] < 3 or not np.isfinite(linear).all() or linear.max() > 1.5:
        raise LayoutError(f"{npy}: expected an [H, W, 3] float array of linear albedo in [0, 1], got shape "
                          f"{linear.shape}, max {np.nanmax(linear):.3g}")
    linear = np.clip(block_mean(linear[..., :3], factor, npy), 0.0, 1.0)
    return linear_to_srgb(torch.from_numpy(np.ascontiguousarray(linear, dtype=np.float32))).numpy()


def _npy(path: Path) -> np.ndarray:
    if not path.is_file():
        raise LayoutError(f"{path}: ground-truth map not found")
    try:
        return np.load(path, allow_pickle=False).astype(np.float32)
    except ValueError as exc:
        raise LayoutError(f"{path}: not a readable .npy array ({exc})") from exc


def import_stanford_orb(src: str | Path, out_dir: str | Path, *, name: str | None = None,
                        ground_truth: str | Path | None = None, resolution: int = BENCHMARK_RESOLUTION) -> Scene:
    """Convert one Stanford-ORB capture (blender representation) into `<out_dir>/<name>/`.

    Args:
        ground_truth: the `ground_truth/` folder (default `<src>/../../ground_truth`).
    Raises:
        LayoutError: naming the file (transforms, frame, mask or ground-truth map missing).
    """
    src = Path(src)
    meta = {s: read_transforms(src / f"transforms_{s}.json") for s in ("train", "test")}
    info = meta["test"].get("gspi", {})
    name = check_name(name or info.get("name") or src.name, "import.name (the imported scene's folder)")
    gt_root = Path(ground_truth) if ground_truth is not None else src.parent.parent / "ground_truth"
    own_gt = gt_root / src.name
    if not own_gt.is_dir():
        log.warning("%s: no ground truth folder: albedo, normals and relighting not imported", own_gt)
    root, frames = Path(out_dir) / name, Frames(src, resolution)
    views, size = {}, None
    for split, m in meta.items():
        views[split] = []
        for i, frame in enumerate(m["frames"]):
            fp = str(frame.get("file_path", ""))
            vid = check_name(Path(fp).name, f"{src / f'transforms_{split}.json'}: frames[{i}].file_path")
            rgb, mask = frames.read(fp)
            size = size or rgb.shape[0]
            K, w2c, c2w = _camera(frame, m.get("camera_angle_x"), rgb.shape[0], f"{src}/transforms_{split}.json")
            vdir = root / split / vid
            write_input_view(vdir, rgb, mask)
            channels = ()
            if split == "test" and own_gt.is_dir():
                factor = frames.factor(read_png(frames.mask_path(fp), channels=1).shape[0])
                _write_gt_maps(own_gt, vid, vdir, c2w, mask, factor, albedo=True)
                channels = ("albedo",)
            views[split].append(View(vid, split, K, w2c, gt_channels=channels))
    relight = _import_novel(src, gt_root, root, frames, views["test"], size) if own_gt.is_dir() else []
    have = {c for vs in views.values() for v in vs for c in v.gt_channels}
    scene = Scene(root=root, name=name, width=size, height=size, views=views, capture_env="unknown",
                  relight_envs=relight, gt_channels=tuple(c for c in GT_CHANNELS if c in have), relit_gt="images",
                  extra={"source": {"format": "stanford_orb", "path": str(src), "ground_truth": str(gt_root),
                                    "resolution": resolution}})
    write_scene_json(scene)
    return scene


def _import_novel(src: Path, gt_root: Path, root: Path, own: Frames, test: list[View], size: int) -> list[str]:
    """Append the relighting views of transforms_novel.json to ``test``; their environment names."""
    path = src / "transforms_novel.json"
    if not path.is_file():
        log.warning("%s: not found: no relighting views", path)
        return []
    envs = []
    for i, frame in enumerate(read_transforms(path)["frames"]):
        other = check_name(str(frame.get("scene_name", "")), f"{path}: frames[{i}].scene_name")
        fp = str(frame.get("file_path", ""))
        vid = check_name(f"{other}_{Path(fp).name}", f"{path}: frames[{i}].file_path")
        frames = Frames(src.parent / other, own.resolution)
        rgb, mask = frames.read(fp)
        K, w2c, c2w = _camera(frame, frame.get("camera_angle_x"), rgb.shape[0], str(path))
        vdir = root / "test" / vid
        write_input_view(vdir, rgb, mask)
        write_exr(vdir / f"relit_{vid}.exr", rgb)
        factor = frames.factor(read_png(frames.mask_path(fp), channels=1).shape[0])
        _write_gt_maps(gt_root / other, Path(fp).name, vdir, c2w, mask, factor, albedo=False)
        env = read_exr(gt_root / other / "env_map" / f"{Path(fp).name}.exr")
        height = env.shape[0] // (EXPORT_ENV_UPSAMPLE if frame.get("gspi_env_upsampled") else 1)
        write_exr(root / "envmaps" / f"{vid}.exr", orb_to_world(env, c2w, height))
        test.append(View(vid, "test", K, w2c, gt_channels=("relight",), relight_envs=(vid,)))
        envs.append(vid)
    return envs


def _export_frame(scene: Scene, v: View, capture: Path, gt: Path, image: np.ndarray, split: str) -> dict:
    vdir = scene.view_dir(v.split, v.id)
    mask = read_view_file(vdir, "mask.png")
    write_exr(capture / split / f"{v.id}.exr", image)
    write_png(capture / f"{split}_mask" / f"{v.id}.png", mask, bits=8)
    c2w = opencv_w2c_to_blender_c2w(v.w2c)
    if split == "test" and (vdir / "normal.exr").is_file():
        n_cam = read_view_file(vdir, "normal.exr") @ c2w[:3, :3]  # row form of R^T n
        (gt / "surface_normal").mkdir(parents=True, exist_ok=True)
        np.save(gt / "surface_normal" / f"{v.id}.npy", n_cam.astype(np.float32))
    if split == "test" and (vdir / "depth.exr").is_file():
        (gt / "z_depth").mkdir(parents=True, exist_ok=True)
        np.save(gt / "z_depth" / f"{v.id}.npy", read_view_file(vdir, "depth.exr")[..., 0])
    return {"file_path": f"{split}/{v.id}", "transform_matrix": c2w.tolist(),
            "camera_angle_x": check_angle_x_camera(scene, v)}


def export_stanford_orb(scene_dir: str | Path, out_dir: str | Path) -> Path:
    """Write a canonical scene as Stanford-ORB's blender representation (module docstring)."""
    scene = read_scene(scene_dir)
    out = Path(out_dir)
    capture, gt = out / "blender_HDR" / scene.name, out / "ground_truth" / scene.name
    novel = []
    for split in ("train", "test"):
        frames = []
        for v in scene.views.get(split, []):
            vdir = scene.view_dir(split, v.id)
            relight_only = v.gt_channels == ("relight",)  # a relighting view (of an imported ORB scene)
            if not relight_only:
                frames.append(_export_frame(scene, v, capture, gt, read_view_file(vdir, "rgb.exr"), split))
            if split == "test" and not relight_only and (vdir / "albedo.png").is_file():
                write_png(gt / "pseudo_gt_albedo" / f"{v.id}.png", read_view_file(vdir, "albedo.png"), bits=8)
            for env in scene.view_relight_envs(v) if split == "test" else []:
                other = check_name(f"{scene.name}-{env}", "exported capture name")
                frame = _export_frame(scene, v, out / "blender_HDR" / other, out / "ground_truth" / other,
                                      read_exr(vdir / f"relit_{env}.exr"), "test")
                c2w = np.asarray(frame["transform_matrix"])
                env_map = read_exr(scene.envmap_path(env))
                write_exr(out / "ground_truth" / other / "env_map" / f"{v.id}.exr",
                          world_to_orb(env_map, c2w, EXPORT_ENV_UPSAMPLE * env_map.shape[0]))
                novel.append({**frame, "scene_name": other, "gspi_env_upsampled": True})
        angle = frames[0]["camera_angle_x"] if frames else 0.0
        write_json_atomic(capture / f"transforms_{split}.json", {"camera_angle_x": angle, "frames": frames,
                                                                 "gspi": {"name": scene.name}})
    write_json_atomic(capture / "transforms_novel.json", {"frames": novel})
    return capture
