"""TensoIR-synthetic (Haian-Jin/TensoIR, dataLoader/tensoIR_*.py) <-> the canonical layout.

CLI (gspi/cli/data.py):
    gspi-data import.src=TensoIR_Synthetic/lego import.format=tensoir out=DIR
    gspi-data export.src=DIR/s000_torus_metal export.format=tensoir out=TENSOIR_DIR

Layout, as TensoIR's loaders read it: a scene folder of view folders `train_NNN/`, `test_NNN/`
(TensoIR lists the folders whose name starts with the split, sorted), each with

* `metadata.json`: `imw`, `imh`, `cam_angle_x` (horizontal FoV, radians), `cam_transform_mat`
  (Blender c2w, 16 comma-separated numbers, row-major), `envmap` (the light of `rgba.png`);
* `rgba_<light>_000.png`: the input image TensoIR trains on (tensoIR_rotation_setting.py with
  configs/single_light: `light_name = sunset`, `light_rotation = [000]`; sRGB, straight alpha),
  `<light>` = metadata.json's `envmap`; read first, then `rgba_<light>.png`, then `rgba.png`
  (which no TensoIR loader reads; the `transforms_*.json` of GS-IR and IRGS point at it as
  `./test_000/rgba`); `rgba_<light>.png`: the view under `<light>` (relighting ground truth,
  tensoIR_relighting_test.py; `<light>_<rot>` = a rotated light, only imported when
  `<light>_<rot>.hdr` exists);
* `albedo.png` (RGBA; TensoIR blends it on white with its alpha and uses the values as LINEAR
  reflectance: no decoding), `normal.png` (RGBA, world normal n = 2 rgb / 255 - 1, blended to
  (0, 0, 1) by alpha, normalised).

Environment maps: `<light>.hdr` (Radiance, lat-long, TensoIR's Environment_Light convention,
which is the layout's: no rotation) in `import.envmaps`, else the first of
`<scene>/../Environment_Maps/high_res_envmaps_1k` (TensoIR's relighting configs),
`.../high_res_envmaps_2k`, `<scene>/../../Environment_Maps/...` that exists. They are
stored as they are (not rescaled: the relit images were rendered with them).

Conversions: cameras as NeRF-synthetic (gspi.data.layouts.nerf_synthetic); rgb.exr and relit_<light>.exr
= sRGB-decoded RGB x alpha (LDR: the renders are clipped at 1), mask = alpha != 0 (TensoIR's
`~(alpha == 0)`); albedo.png = the sRGB encoding of TensoIR's linear albedo (its values blended
on white by alpha), 0 outside the mask; normal.exr = TensoIR's decoded normal inside the mask.
docs/DATA.md "TensoIR's conventions" lists each with the authors' line. TensoIR has no roughness, metallic or depth
ground truth: scene.json `gt_channels` = [albedo, relight] (relight only with environment
maps), `relit_gt` = images; train views carry albedo (their relit images are not imported).

Export writes the same files (8-bit PNGs; albedo.png as linear values, the input image as
`rgba_<capture>_000.png` and `rgba.png`; `transforms_{split}.json` for GS-IR/IRGS too) under
`<out>/<scene name>/` and the scene's environments as `<out>/Environment_Maps/
high_res_envmaps_1k/<env>.hdr`, so that `import.src=<out>/<scene name>` finds them. A round
trip keeps cameras to float rounding, masks exactly, albedo, normals and images within 8-bit
quantisation (values above 1 clipped) and environments within RGBE rounding (2^-8).
"""
from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import torch

from eval.common.atomic import write_json_atomic
from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.common.imageio import read_exr, write_exr
from eval.common.layout import SPLITS, LayoutError, Scene, View, check_name, read_json_object, read_scene, \
    read_view_file, write_material, write_scene_json, write_view_file
from eval.radiance_hdr import read_hdr, write_hdr
from gspi.data.layouts.nerf_synthetic import blender_c2w_to_opencv_w2c, check_angle_x_camera, intrinsics_from_angle_x, \
    linear_from_rgba, opencv_w2c_to_blender_c2w, read_rgba, rgba_from_linear, write_input_view, write_rgba

log = logging.getLogger(__name__)
VIEW_DIR = re.compile(r"^(train|val|test)_(\d+)$")
ENVMAP_DIRS = ("Environment_Maps/high_res_envmaps_1k", "Environment_Maps/high_res_envmaps_2k")
EXPORT_ENVMAPS = ENVMAP_DIRS[0]


def view_folders(src: Path) -> dict[str, list[Path]]:
    """split -> its view folders in TensoIR's (sorted) order."""
    out: dict[str, list[Path]] = {}
    for p in sorted(src.iterdir()) if src.is_dir() else []:
        m = VIEW_DIR.match(p.name)
        if m and p.is_dir():
            out.setdefault(m.group(1), []).append(p)
    return {s: out[s] for s in SPLITS if s in out}


def find_envmaps(src: Path, envmaps: str | Path | None) -> Path | None:
    if envmaps is not None:
        if not Path(envmaps).is_dir():
            raise LayoutError(f"{envmaps}: import.envmaps folder not found")
        return Path(envmaps)
    for base in (src.parent, src.parent.parent):
        for sub in ENVMAP_DIRS:
            if (base / sub).is_dir():
                return base / sub
    return None


def read_camera(meta_path: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    """(metadata, K [3, 3], OpenCV w2c [4, 4]) of one view's metadata.json."""
    meta = read_json_object(meta_path, what="TensoIR metadata.json (the view's camera)")
    try:
        c2w = np.array([float(x) for x in str(meta["cam_transform_mat"]).split(",")], np.float64)
        w, h, angle = int(meta["imw"]), int(meta["imh"]), float(meta["cam_angle_x"])
    except (KeyError, ValueError) as exc:
        raise LayoutError(f"{meta_path}: needs imw, imh, cam_angle_x and cam_transform_mat ({exc})") from exc
    if c2w.shape != (16,) or not np.isfinite(c2w).all():
        raise LayoutError(f"{meta_path}: cam_transform_mat must hold 16 finite numbers")
    return meta, intrinsics_from_angle_x(angle, w, h), blender_c2w_to_opencv_w2c(c2w.reshape(4, 4))


def relight_names(folders: list[Path], capture: str, envdir: Path | None) -> list[str]:
    """Lights every test view has a `rgba_<light>.png` of and whose `<light>.hdr` exists."""
    if not folders or envdir is None:
        return []
    sets = [{p.name[5:-4] for p in f.glob("rgba_*.png")} for f in folders]
    common = set.intersection(*sets) - {capture}
    return sorted(n for n in common if (envdir / f"{n}.hdr").is_file())


def input_image(folder: Path, light: str) -> Path:
    """The view's input image as TensoIR's single-light training reads it: ``rgba_<light>_000.png``
    (tensoIR_rotation_setting.py with configs/single_light: light_name = sunset, light_rotation =
    [000]); else ``rgba_<light>.png`` (the relighting loader's name for the same light); else
    ``rgba.png``, which none of TensoIR's loaders reads (logged)."""
    for name in (f"rgba_{light}_000.png", f"rgba_{light}.png"):
        if (folder / name).is_file():
            return folder / name
    if (folder / "rgba.png").is_file():
        log.info("%s: no rgba_%s_000.png: reading rgba.png, which TensoIR's loaders do not read", folder, light)
        return folder / "rgba.png"
    raise LayoutError(f"{folder}: no rgba_{light}_000.png, rgba_{light}.png or rgba.png: the view's input "
                      f"image (light {light!r} from metadata.json's envmap)")


def albedo_srgb(rgba: np.ndarray) -> np.ndarray:
    """gspi's sRGB-encoded albedo of a TensoIR ``albedo.png``: TensoIR blends it on white with its
    alpha and uses the values as LINEAR reflectance (tensoIR_rotation_setting.py and
    tensoIR_relighting_test.py: ``albedo[:, :3] * a + (1 - a)``, no decoding), so they are
    encoded here, as gspi's albedo.png holds sRGB (docs/FORMAT.md)."""
    linear = rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])
    return linear_to_srgb(torch.from_numpy(np.ascontiguousarray(linear, dtype=np.float32))).numpy()


def albedo_linear_rgba(srgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The inverse for the exporter: gspi's sRGB albedo as TensoIR's linear ``albedo.png`` values."""
    linear = srgb_to_linear(torch.from_numpy(np.ascontiguousarray(srgb, dtype=np.float32))).numpy()
    return np.concatenate([linear, mask], -1)


def tensoir_mask(rgba: np.ndarray) -> np.ndarray:
    """[H, W, 1] bool: TensoIR's foreground, alpha != 0 (``~(img[:, -1:] == 0)``)."""
    return rgba[..., 3:] != 0


def _import_view(folder: Path, vdir: Path, meta: dict, relight: list[str]) -> tuple[int, int]:
    rgba = read_rgba(input_image(folder, str(meta.get("envmap", "sunset"))))
    mask = tensoir_mask(rgba)
    write_input_view(vdir, linear_from_rgba(rgba), mask)
    write_material(vdir, "albedo", albedo_srgb(read_rgba(folder / "albedo.png")) * mask)
    if (folder / "normal.png").is_file():  # TensoIR: 2 v - 1, blended to (0, 0, 1) by alpha, normalised
        normal = read_rgba(folder / "normal.png")
        a = normal[..., 3:]
        n = (normal[..., :3] * 2.0 - 1.0) * a + np.array([0.0, 0.0, 1.0]) * (1.0 - a)
        n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        write_view_file(vdir, "normal.exr", (n * mask).astype(np.float32))
    for light in relight:
        write_exr(vdir / f"relit_{light}.exr", linear_from_rgba(read_rgba(folder / f"rgba_{light}.png")))
    return rgba.shape[0], rgba.shape[1]


def import_tensoir(src: str | Path, out_dir: str | Path, *, name: str | None = None,
                   envmaps: str | Path | None = None) -> Scene:
    """Convert a TensoIR-synthetic scene folder into `<out_dir>/<name>/` (module docstring).

    Raises:
        LayoutError: naming the file: no view folders, a view without metadata.json or images.
    """
    src = Path(src)
    folders = view_folders(src)
    if not folders:
        raise LayoutError(f"{src}: no train_NNN/ or test_NNN/ view folders (TensoIR-synthetic layout)")
    metas = {s: [read_camera(f / "metadata.json") for f in fs] for s, fs in folders.items()}
    first = next(iter(metas.values()))[0][0]
    info = first.get("gspi", {})
    name = check_name(name or info.get("scene") or src.name, "import.name (the imported scene's folder)")
    first_meta = next(iter(folders.values()))[0] / "metadata.json"
    capture = check_name(str(first.get("envmap", "unknown")), f"{first_meta}: envmap")
    envdir = find_envmaps(src, envmaps)
    relight = relight_names(folders.get("test", []), capture, envdir)
    if envdir is None:
        log.warning("%s: no Environment_Maps folder found (import.envmaps): relit ground truth not imported", src)
    root = Path(out_dir) / name
    views, size = {}, None
    for split, fs in folders.items():
        views[split] = []
        for folder, (meta, K, w2c) in zip(fs, metas[split]):
            vid = check_name(str(meta.get("gspi", {}).get("id", folder.name)), f"{folder}/metadata.json: gspi.id")
            hw = _import_view(folder, root / split / vid, meta, relight if split == "test" else [])
            if size is not None and hw != size:
                raise LayoutError(f"{folder}: size {hw} differs from earlier views {size}")
            size = hw
            views[split].append(View(vid, split, K, w2c, gt_channels=None if split == "test" else ("albedo",)))
    for env in [capture, *relight] if envdir is not None else []:
        if (envdir / f"{env}.hdr").is_file():
            write_exr(root / "envmaps" / f"{env}.exr", read_hdr(envdir / f"{env}.hdr"))
    scene = Scene(root=root, name=name, width=size[1], height=size[0], views=views, capture_env=capture,
                  relight_envs=relight, gt_channels=("albedo", "relight") if relight else ("albedo",),
                  relit_gt="images", extra={"source": {"format": "tensoir", "path": str(src),
                                                       "envmaps": None if envdir is None else str(envdir)}})
    write_scene_json(scene)
    return scene


def _export_view(scene: Scene, v: View, folder: Path, angle: float, bits: int) -> dict:
    vdir = scene.view_dir(v.split, v.id)
    mask = read_view_file(vdir, "mask.png")
    image = rgba_from_linear(read_view_file(vdir, "rgb.exr"), mask)
    write_rgba(folder / f"rgba_{scene.capture_env}_000.png", image, bits=bits)  # what TensoIR trains on
    write_rgba(folder / "rgba.png", image, bits=bits)  # GS-IR's / IRGS's transforms_*.json point at it
    if (vdir / "albedo.png").is_file():
        write_rgba(folder / "albedo.png", albedo_linear_rgba(read_view_file(vdir, "albedo.png"), mask), bits=bits)
    if (vdir / "normal.exr").is_file():
        n = read_view_file(vdir, "normal.exr")
        write_rgba(folder / "normal.png", np.concatenate([(n + 1.0) / 2.0, mask], -1), bits=bits)
    for env in scene.view_relight_envs(v) if v.split == "test" else []:
        relit = vdir / f"relit_{env}.exr"
        if relit.is_file():
            write_rgba(folder / f"rgba_{env}.png", rgba_from_linear(read_exr(relit), mask), bits=bits)
    c2w = opencv_w2c_to_blender_c2w(v.w2c)
    meta = {"imw": scene.width, "imh": scene.height, "cam_angle_x": angle,
            "cam_transform_mat": ",".join(repr(float(x)) for x in c2w.reshape(-1)), "envmap": scene.capture_env,
            "gspi": {"id": v.id, "scene": scene.name}}
    write_json_atomic(folder / "metadata.json", meta)
    return {"file_path": f"./{folder.name}/rgba", "transform_matrix": c2w.tolist()}


def export_tensoir(scene_dir: str | Path, out_dir: str | Path, *, bits: int = 8) -> Path:
    """Write a canonical scene as `<out_dir>/<scene name>/` in the TensoIR layout (module docstring).

    Raises:
        LayoutError: a camera TensoIR's metadata cannot hold (fx != fy or off-centre).
    """
    scene = read_scene(scene_dir)
    out = Path(out_dir) / scene.name
    for split, views in scene.views.items():
        frames, angle = [], 0.0
        for k, v in enumerate(views):
            angle = check_angle_x_camera(scene, v)
            frames.append(_export_view(scene, v, out / f"{split}_{k:03d}", angle, bits))
        write_json_atomic(out / f"transforms_{split}.json", {"camera_angle_x": angle, "frames": frames})
    for env in [scene.capture_env, *scene.relight_envs]:
        if scene.envmap_path(env).is_file():
            write_hdr(Path(out_dir) / EXPORT_ENVMAPS / f"{env}.hdr", read_exr(scene.envmap_path(env)))
    return out
