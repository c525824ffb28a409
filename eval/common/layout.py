"""The canonical on-disk layout of scenes, datasets and predictions (docs/FORMAT.md).

Everything that reads or writes `scene.json`, `splits.json`, `meta.json` or a per-view folder
goes through this module, so the evaluator, the pipeline and every baseline adapter agree.
Errors are `LayoutError`s that name the file and the problem.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eval.common.atomic import write_json_atomic
from eval.common.errors import StatedError
from eval.common.imageio import ImageFormatError, read_exr, read_png, write_exr, write_png

FORMAT_VERSION = 1
CAMERA_CONVENTION = "opencv"  # x right, y down, z forward; w2c maps world -> camera
MATERIAL_CHANNELS = ("albedo", "roughness", "metallic")
GT_CHANNELS = (*MATERIAL_CHANNELS, "relight")  # what a ground truth can provide to be scored
RELIT_GT = ("shaded", "images")  # relit GT: split-sum of the GT maps | the stored relit_<env>.exr
SPLITS = ("train", "val", "test")

# file name -> (reader kind, channels). The single table of per-view files.
VIEW_FILES = {
    "rgb.exr": ("exr", 3),        # linear HDR input radiance, black background
    "rgb.png": ("png", 3),        # 8-bit sRGB preview of rgb.exr (clamp + sRGB), not scored
    "albedo.png": ("png", 3),     # 16-bit, sRGB-encoded base colour
    "roughness.png": ("png", 1),  # 16-bit, linear
    "metallic.png": ("png", 1),   # 16-bit, linear
    "normal.exr": ("exr", 3),     # world-space unit normals, 0 outside the mask
    "depth.exr": ("exr", 1),      # camera-space z (OpenCV), world units, 0 outside the mask
    "mask.png": ("png", 1),       # 8-bit, 255 = foreground
    "alpha.png": ("png", 1),      # predictions only, optional: 16-bit, the method's rendered opacity
    "outside_brdf.png": ("png", 1),  # GT only, optional: 8-bit, 255 = a pixel that shows a material
                                     # feature the metallic-roughness BRDF cannot (glTF BLEND, KHR_materials_*)
}
PREDICTION_ONLY_FILES = ("alpha.png",)
OPTIONAL_GT_FILES = ("outside_brdf.png",)
GT_VIEW_FILES = tuple(n for n in VIEW_FILES if n not in PREDICTION_ONLY_FILES + OPTIONAL_GT_FILES)  # every GT view has these


class LayoutError(StatedError, ValueError):
    """A scene, dataset or prediction folder does not follow docs/FORMAT.md."""


NAME_RULE = ("a string that is one path component: not empty, no '/', '\\', NUL or control characters, "
             "not starting with '.', at most 255 bytes")


def check_name(name, where: str) -> str:
    """``name`` if it is safe as ONE folder or file name (scene names, view ids, split names).

    Every name a data file gives (scene.json ``name``, view ``id``, splits.json entries, an
    import's scene name) becomes a path component of some output; this is the one check that
    keeps every writer inside its folder (``../../x`` would not be).

    Raises:
        LayoutError: naming ``where`` (the file and key) and the rule.
    """
    ok = isinstance(name, str) and name not in ("", ".", "..") and not name.startswith(".") \
        and not any(c in name for c in "/\\") and all(ord(c) >= 32 and ord(c) != 127 for c in name) \
        and len(name.encode("utf-8", "surrogatepass")) <= 255
    if not ok:
        raise LayoutError(f"{where}: {name!r} is not allowed as a name ({NAME_RULE})")
    return name


@dataclass(frozen=True)
class View:
    """One camera of a scene: `K` pixel intrinsics (pixel centres at +0.5), `w2c` OpenCV."""

    id: str
    split: str
    K: np.ndarray    # [3, 3]
    w2c: np.ndarray  # [4, 4]
    gt_channels: tuple[str, ...] | None = None   # this view's GT channels (None: the scene's)
    relight_envs: tuple[str, ...] | None = None  # this view's relit GT envs (None: the scene's)

    def __post_init__(self) -> None:
        check_name(self.id, f"view id (split {self.split!r})")
        check_name(self.split, "split name")

    @property
    def camera_center(self) -> np.ndarray:  # [3] world
        R, t = self.w2c[:3, :3], self.w2c[:3, 3]
        return -R.T @ t


@dataclass
class Scene:
    """A ground-truth scene folder: `scene.json` plus `<split>/<view id>/` and `envmaps/`."""

    root: Path
    name: str
    width: int
    height: int
    views: dict[str, list[View]]
    capture_env: str
    relight_envs: list[str]
    extra: dict = field(default_factory=dict)  # free-form metadata (generator settings, source)
    gt_channels: tuple[str, ...] = GT_CHANNELS  # what the ground truth provides (imported datasets: less)
    relit_gt: str = "shaded"                     # RELIT_GT: how the relit ground truth is obtained

    def __post_init__(self) -> None:
        check_name(self.name, f"{Path(self.root) / 'scene.json'}: name")

    def view_gt_channels(self, view: View) -> tuple[str, ...]:
        return self.gt_channels if view.gt_channels is None else view.gt_channels

    def view_relight_envs(self, view: View) -> list[str]:
        """The environments whose relit ground truth this view has (none if it lacks "relight")."""
        if "relight" not in self.view_gt_channels(view):
            return []
        return list(self.relight_envs if view.relight_envs is None else view.relight_envs)

    def view_dir(self, split: str, view_id: str) -> Path:
        return self.root / split / view_id

    def envmap_path(self, name: str) -> Path:
        return self.root / "envmaps" / f"{name}.exr"

    def split_views(self, split: str) -> list[View]:
        if split not in self.views:
            raise LayoutError(f"{self.root / 'scene.json'}: scene has no split {split!r} "
                              f"(has {sorted(self.views)})")
        return self.views[split]


def _matrix(value, shape: tuple[int, int], where: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != shape or not np.isfinite(arr).all():
        raise LayoutError(f"{where}: expected a finite {shape[0]}x{shape[1]} matrix, got {value!r}")
    return arr


def read_json_object(path: str | Path, *, error: type[Exception] = LayoutError, what: str = "file") -> dict:
    """A JSON file that must hold an object; ``error`` naming the file otherwise (missing,
    truncated, not an object, nested too deep to parse). The one JSON-object reader of eval/:
    run records and sweeps pass their own error class and what the file is."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: {what} not found")
    try:
        data = json.loads(path.read_text())
    except (ValueError, RecursionError) as exc:  # RecursionError: absurdly nested JSON
        raise error(f"{path}: invalid JSON ({str(exc)[:200] or type(exc).__name__})") from exc
    if not isinstance(data, dict):
        raise error(f"{path}: expected a JSON object, found {type(data).__name__}")
    return data



def _channel_list(value, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(c, str) and c in GT_CHANNELS for c in value):
        raise LayoutError(f"{where}: expected a list of channels from {list(GT_CHANNELS)}, got {value!r}")
    return tuple(c for c in GT_CHANNELS if c in value)


def _env_list(value, where: str) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise LayoutError(f"{where}: expected a list of environment names, got {value!r}")
    return tuple(check_name(e, f"{where}[{i}]") for i, e in enumerate(value))


def _ground_truth_fields(data: dict, path: Path) -> tuple[tuple[str, ...], str]:
    """scene.json ``gt_channels`` (default all) and ``relit_gt`` (default shaded), checked:
    shading the relit ground truth needs every material map."""
    channels = _channel_list(data["gt_channels"], f"{path}: gt_channels") if "gt_channels" in data \
        else GT_CHANNELS
    relit = data.get("relit_gt", "shaded")
    if relit not in RELIT_GT:
        raise LayoutError(f"{path}: relit_gt must be one of {list(RELIT_GT)}, got {relit!r}")
    if relit == "shaded" and "relight" in channels and not set(MATERIAL_CHANNELS) <= set(channels):
        raise LayoutError(f"{path}: relit_gt 'shaded' needs albedo, roughness and metallic ground "
                          f"truth, gt_channels has {list(channels)}")
    return channels, relit


def read_scene(scene_dir: str | Path) -> Scene:
    """Parse and validate `<scene_dir>/scene.json`."""
    root = Path(scene_dir)
    path = root / "scene.json"
    data = read_json_object(path)
    for key in ("name", "width", "height", "views", "capture_env", "relight_envs"):
        if key not in data:
            raise LayoutError(f"{path}: missing key {key!r}")
    if data.get("camera_convention", CAMERA_CONVENTION) != CAMERA_CONVENTION:
        raise LayoutError(f"{path}: camera_convention must be {CAMERA_CONVENTION!r}")
    check_name(data["name"], f"{path}: name")
    if not isinstance(data["views"], dict):
        raise LayoutError(f"{path}: views must be an object {{split: [views]}}, got {type(data['views']).__name__}")
    for key in ("width", "height"):
        if isinstance(data[key], bool) or not isinstance(data[key], int) or not 1 <= data[key] <= 16384:
            raise LayoutError(f"{path}: {key} must be an integer in [1, 16384], got {data[key]!r}")
    if not isinstance(data["relight_envs"], list):
        raise LayoutError(f"{path}: relight_envs must be a list of environment names")
    for i, env in enumerate([data["capture_env"], *data["relight_envs"]]):
        check_name(env, f"{path}: " + ("capture_env" if i == 0 else f"relight_envs[{i - 1}]"))
    views: dict[str, list[View]] = {}
    for split, entries in data["views"].items():
        check_name(split, f"{path}: views.{split}")
        if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
            raise LayoutError(f"{path}: views.{split} must be a list of objects {{id, K, w2c}}")
        seen = set()
        views[split] = []
        for i, entry in enumerate(entries):
            where = f"{path}: views.{split}[{i}]"
            if "id" not in entry:
                raise LayoutError(f"{where}: missing 'id'")
            if not isinstance(entry["id"], (str, int)) or isinstance(entry["id"], bool):
                raise LayoutError(f"{where}.id: expected a string, got {entry['id']!r}")
            vid = check_name(str(entry["id"]), f"{where}.id")
            if vid in seen:
                raise LayoutError(f"{where}: duplicate view id {vid!r}")
            seen.add(vid)
            views[split].append(View(
                vid, split, _matrix(entry.get("K"), (3, 3), where + ".K"),
                _matrix(entry.get("w2c"), (4, 4), where + ".w2c"),
                _channel_list(entry["gt_channels"], where + ".gt_channels") if "gt_channels" in entry else None,
                _env_list(entry["relight_envs"], where + ".relight_envs") if "relight_envs" in entry else None))
    gt_channels, relit_gt = _ground_truth_fields(data, path)
    known = {"format", "format_version", "name", "width", "height", "camera_convention", "views",
             "capture_env", "relight_envs", "gt_channels", "relit_gt"}
    return Scene(root=root, name=str(data["name"]), width=int(data["width"]),
                 height=int(data["height"]), views=views, capture_env=str(data["capture_env"]),
                 relight_envs=[str(e) for e in data["relight_envs"]],
                 extra={k: v for k, v in data.items() if k not in known},
                 gt_channels=gt_channels, relit_gt=relit_gt)


def write_scene_json(scene: Scene) -> Path:
    """Write `scene.json` for `scene` (views in their stored order)."""
    data = {
        "format": "gspi-scene", "format_version": FORMAT_VERSION, "name": scene.name,
        "width": scene.width, "height": scene.height, "camera_convention": CAMERA_CONVENTION,
        "capture_env": scene.capture_env, "relight_envs": list(scene.relight_envs),
        "views": {split: [_view_entry(v) for v in vs] for split, vs in scene.views.items()},
        **scene.extra,
    }
    if tuple(scene.gt_channels) != GT_CHANNELS or scene.relit_gt != "shaded":  # generated scenes: unchanged
        data.update(gt_channels=list(scene.gt_channels), relit_gt=scene.relit_gt)
    scene.root.mkdir(parents=True, exist_ok=True)
    path = scene.root / "scene.json"
    write_json_atomic(path, data)
    return path


def _view_entry(v: View) -> dict:
    entry = {"id": v.id, "K": v.K.tolist(), "w2c": v.w2c.tolist()}
    if v.gt_channels is not None:
        entry["gt_channels"] = list(v.gt_channels)
    if v.relight_envs is not None:
        entry["relight_envs"] = list(v.relight_envs)
    return entry


def scene_dir_in(data_dir: str | Path, name: str) -> Path | None:
    """The folder of scene ``name`` given a dataset folder (``<data>/<name>/``) or that one scene's
    own folder (``gspi-run data=<scene folder>`` names its scene after the folder); None if neither."""
    data_dir = Path(data_dir)
    if (data_dir / name / "scene.json").is_file():
        return data_dir / name
    if data_dir.name == name and (data_dir / "scene.json").is_file():
        return data_dir
    return None


def read_splits(dataset_dir: str | Path) -> dict[str, list[str]]:
    """`<dataset>/splits.json` = {"train": [scene names], "val": [...], "test": [...]}."""
    path = Path(dataset_dir) / "splits.json"
    data = read_json_object(path)
    out = {}
    for split, names in data.items():
        if not isinstance(names, list):
            raise LayoutError(f"{path}: split {split!r} must be a list of scene names")
        out[split] = [check_name(n, f"{path}: {split}[{i}]") for i, n in enumerate(names)]
    return out


def merge_splits(out_dir: str | Path, added: dict[str, list[str]]) -> dict[str, list[str]]:
    """Add scene names to `<out>/splits.json` (created if missing); returns the result."""
    path = Path(out_dir) / "splits.json"
    splits = read_splits(out_dir) if path.is_file() else {"train": [], "val": [], "test": []}
    for split, names in added.items():
        splits[split] = sorted(set(splits.get(split, [])) | set(names))
    write_json_atomic(path, splits)
    return splits


def read_view_file(view_dir: Path, name: str, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read one per-view file of the layout as float32 HxWxC (see VIEW_FILES); ``shape`` (H, W),
    when given, is checked from the file's header before its pixels are decoded."""
    if name not in VIEW_FILES:
        raise ValueError(f"unknown per-view file {name!r}; allowed: {', '.join(VIEW_FILES)}")
    kind, channels = VIEW_FILES[name]
    path = Path(view_dir) / name
    try:
        arr = read_exr(path, shape=shape) if kind == "exr" else read_png(path, channels=channels, shape=shape)
    except ImageFormatError as exc:
        raise LayoutError(str(exc)) from exc
    if arr.shape[-1] != channels:
        raise LayoutError(f"{path}: expected {channels} channel(s), found {arr.shape[-1]}")
    return arr


def no_images_message(pred_root: Path, scene: Scene, split: str, channels: list[str]) -> str:
    """Why a prediction folder gave nothing to score: the files looked for (in ``scene``, the
    first scene present) and what the folder holds instead (a `Test/` split, `000` instead of
    `t00`, EXR maps)."""
    pred_scene = pred_root if pred_root.name == scene.name and (pred_root / "scene.json").is_file() \
        else pred_root / scene.name
    views = [v.id for v in scene.split_views(split)]
    found = sorted(p.name for p in pred_scene.iterdir()) if pred_scene.is_dir() else []
    split_dir = pred_scene / split
    found_views = sorted(p.name for p in split_dir.iterdir()) if split_dir.is_dir() else []
    files = [material_file(c) for c in MATERIAL_CHANNELS if c in channels or (c == "albedo" and "relight" in channels)]
    return (f"{pred_root}: 0 images scored. Looked for {pred_scene}/{split}/<view>/"
            f"{{{','.join(files) or 'nothing: eval.channels'}}} with views {views[:4]}"
            f"{' ...' if len(views) > 4 else ''} (scene.json of {scene.name}); found in {pred_scene.name}/: "
            f"{found[:6]}, in {split}/: {found_views[:6]}. Material maps are 16-bit PNGs named as in "
            "docs/FORMAT.md (not EXR); view folders are named by the view ids of scene.json")


def material_file(channel: str) -> str:
    if channel not in MATERIAL_CHANNELS:
        raise ValueError(f"unknown material channel {channel!r}; allowed: {MATERIAL_CHANNELS}")
    return f"{channel}.png"


def write_material(view_dir: Path, channel: str, values: np.ndarray) -> Path:
    """Write a material map in its canonical encoding (16-bit PNG).

    Args:
        values: albedo HxWx3 already sRGB-encoded in [0, 1]; roughness/metallic HxW(x1) linear.
    """
    path = Path(view_dir) / material_file(channel)
    write_png(path, values, bits=16)
    return path


def write_view_file(view_dir: Path, name: str, values: np.ndarray) -> Path:
    """Write any per-view file in its canonical encoding (see VIEW_FILES)."""
    if name not in VIEW_FILES:
        raise ValueError(f"unknown per-view file {name!r}; allowed: {', '.join(VIEW_FILES)}")
    kind, _ = VIEW_FILES[name]
    path = Path(view_dir) / name
    if kind == "exr":
        write_exr(path, values)
    else:
        write_png(path, values, bits=8 if name in ("rgb.png", "mask.png", "outside_brdf.png") else 16)
    return path


def read_meta(pred_scene_dir: Path) -> dict:
    """`<pred>/<scene>/meta.json`: {"method": str, "runtime_s": {"material", "end_to_end"}}.

    A missing file is allowed (e.g. a scene folder evaluated as the oracle): returns {}.
    """
    path = Path(pred_scene_dir) / "meta.json"
    if not path.exists():
        return {}
    data = read_json_object(path)
    runtime = data.get("runtime_s", {})
    if runtime is None:
        runtime = data["runtime_s"] = {}
    if not isinstance(runtime, dict):
        raise LayoutError(f"{path}: runtime_s must be an object {{material, end_to_end}}, got {runtime!r}")
    if "method" in data and not isinstance(data["method"], str):
        raise LayoutError(f"{path}: method must be a string, got {data['method']!r}")
    if "config_hash" in data and not isinstance(data["config_hash"], str):
        raise LayoutError(f"{path}: config_hash must be a string, got {data['config_hash']!r}")
    for key, value in runtime.items():
        if value is not None and not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise LayoutError(f"{path}: runtime_s.{key} must be a finite number or null")
    return data


def write_meta(pred_scene_dir: Path, *, method: str, material_s: float | None,
               end_to_end_s: float | None, geometry_s: float | None = None, **extra) -> Path:
    """`meta.json`: runtimes in seconds (None = unknown); `geometry` only when known."""
    path = Path(pred_scene_dir) / "meta.json"
    runtime = {"material": material_s, "end_to_end": end_to_end_s}
    if geometry_s is not None:
        runtime["geometry"] = geometry_s
    write_json_atomic(path, {"method": method, "runtime_s": runtime, **extra})
    return path
