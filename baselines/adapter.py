"""The common part of the external-system adapters (docs/BASELINES.md).

An adapter moves one canonical scene (docs/FORMAT.md) into the input layout an external
inverse-rendering system reads (`export`), builds the command lines that train it and render
its test views from a checkout of its official repository (`commands`, `run`), and converts the
system's output folder back into the canonical prediction layout (`import_outputs`).

The method config (`conf/method/<system>.yaml`, a mapping) carries every option: the repository
and checkout, the command templates and the options that change how outputs are read. Each
system module (`baselines/<system>.py`) holds only what is specific to it: `open_outputs`
(locate and validate the output folder) and `read_view` (the maps of the k-th test view).
"""
from __future__ import annotations

import importlib
import shlex
import shutil
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from baselines.runtime import command_stages, given_runtime, read_runtime, split_seconds
from eval.common.atomic import write_json_atomic
from eval.common.colorspace import linear_to_srgb
from eval.common.conf import CONF_DIR
from eval.common.imageio import ImageFormatError, read_png
from eval.common.layout import MATERIAL_CHANNELS, Scene, View, read_scene, write_material, write_meta, write_view_file

RUNTIME_FILE = "gspi_runtime.json"  # written into the model dir by `Adapter.run`
METHOD_CONF_DIR = Path(CONF_DIR) / "method"


class AdapterError(ValueError):
    """A system's output (or input) folder is missing a file or holds something unexpected.

    The message names the file or folder and what is missing or wrong.
    """


# ----------------------------------------------------------------------------- small helpers

def as_dict(cfg: Mapping | None) -> dict:
    """A plain dict of a method config (DictConfig or mapping), interpolations resolved."""
    if cfg is None:
        return {}
    try:
        from omegaconf import DictConfig, OmegaConf
        if isinstance(cfg, DictConfig):
            return OmegaConf.to_container(cfg, resolve=True)
    except ImportError:  # omegaconf is a dependency; plain dicts work without it
        pass
    return dict(cfg)


def option(cfg: Mapping, key: str, allowed: tuple | None = None):
    """`cfg[key]`, required; with `allowed`, the value must be one of them."""
    if key not in cfg:
        raise AdapterError(f"method config {cfg.get('name', '?')!r}: missing option {key!r}")
    value = cfg[key]
    if allowed is not None and value not in allowed:
        raise ValueError(f"option {key}={value!r}; allowed: {', '.join(map(str, allowed))}")
    return value


def srgb_encode(x_linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB-encoded [0, 1] (IEC 61966-2-1, eval.common.colorspace), any shape."""
    return linear_to_srgb(torch.from_numpy(np.asarray(x_linear, np.float64))).numpy()


def read_output_png(path: Path, what: str) -> np.ndarray:
    """Read a system's (8-bit) PNG as float64 HxWxC in [0, 1] (v / 255); alpha dropped.

    Args:
        what: what the file should hold, for the error message ("base colour of test view 2").
    Raises:
        AdapterError: the file is missing or unreadable (names the file and `what`).
    """
    path = Path(path)
    if not path.is_file():
        raise AdapterError(f"{path}: missing ({what})")
    try:
        return read_png(path).astype(np.float64)
    except ImageFormatError as exc:
        raise AdapterError(f"{exc} ({what})") from exc


def grey_channel(image: np.ndarray, path: Path) -> np.ndarray:
    """HxW from a grey map saved as 1 channel or as 3 equal channels (torchvision save_image).

    Raises:
        AdapterError: a 3-channel image whose channels differ (not a grey map).
    """
    if image.shape[-1] == 1:
        return image[..., 0]
    if not (np.array_equal(image[..., 0], image[..., 1])
            and np.array_equal(image[..., 0], image[..., 2])):
        raise AdapterError(f"{path}: expected a grey map (3 equal channels), channels differ")
    return image[..., 0]


def split_panels(image: np.ndarray, count: int, path: Path) -> list[np.ndarray]:
    """Split an image of `count` equal panels placed side by side: HxW'xC -> count x HxWxC."""
    width = image.shape[1]
    if width % count:
        raise AdapterError(f"{path}: width {width} is not {count} equal panels side by side")
    w = width // count
    return [image[:, k * w:(k + 1) * w] for k in range(count)]


def find_iteration_dir(parent: Path, prefix: str, iteration, what: str) -> Path:
    """`<parent>/<prefix><iteration>`; `iteration=None` picks the only or highest numeric one.

    Raises:
        AdapterError: the parent or the requested folder is missing, or the choice is ambiguous.
    """
    parent = Path(parent)
    if iteration is not None:
        path = parent / f"{prefix}{iteration}"
        if not path.is_dir():
            found = sorted(p.name for p in parent.glob(prefix + "*")) if parent.is_dir() else []
            raise AdapterError(f"{path}: missing folder ({what}); found {found or 'none'}")
        return path
    if not parent.is_dir():
        raise AdapterError(f"{parent}: missing folder ({what})")
    found = sorted(p for p in parent.glob(prefix + "*") if p.is_dir())
    if not found:
        raise AdapterError(f"{parent}: no {prefix}<iteration> folder ({what})")
    if len(found) == 1:
        return found[0]
    numeric = [p for p in found if p.name[len(prefix):].isdigit()]
    if len(numeric) != len(found):
        raise AdapterError(f"{parent}: several {prefix}* folders {[p.name for p in found]}; "
                           "set the adapter option iteration=<N>")
    return max(numeric, key=lambda p: int(p.name[len(prefix):]))


def first_existing(candidates: list[Path], what: str) -> Path:
    """The first folder of `candidates` that exists, else an error listing all of them."""
    for path in candidates:
        if Path(path).is_dir():
            return Path(path)
    raise AdapterError(f"none of {', '.join(map(str, candidates))} exists ({what})")


def export_blender_scene(scene_dir: Path, out_dir: Path) -> Path:
    """Canonical scene -> NeRF-synthetic folder (transforms_*.json + 8-bit RGBA PNGs).

    Reuses gspi.data.layouts.nerf_synthetic (Blender/OpenGL c2w, `camera_angle_x`, frames in the
    scene's view order, alpha = mask). The ground-truth maps and environment maps that exporter
    also copies are removed: a system must see only the images, like the in-house pipeline.
    """
    from gspi.data.layouts.nerf_synthetic import MAP_SUFFIXES, export_nerf_synthetic

    out = export_nerf_synthetic(scene_dir, out_dir, bits=8)
    for suffix in MAP_SUFFIXES.values():
        for path in out.glob(f"*/*{suffix}"):
            path.unlink()
    shutil.rmtree(out / "envmaps", ignore_errors=True)
    return out


def skip_train_flag(cfg: Mapping) -> str:
    """`--skip_train` unless `render_lattice: true` asks the render command for the training
    (= lattice) views too, for lattice-view evaluation (`eval.split=lattice`)."""
    return "" if option(cfg, "render_lattice", (True, False)) else "--skip_train"


def check_path_free_of(path: Path, words: tuple[str, ...], system: str) -> None:
    """Some loaders switch dataset readers on substrings of the data path: refuse those."""
    hits = [w for w in words if w in str(Path(path).resolve())]
    if hits:
        raise AdapterError(f"{path}: the path contains {hits}, which makes {system}'s loader "
                           "read another dataset format; export elsewhere")


# ----------------------------------------------------------------------------- the adapter

class Adapter:
    """Base adapter; subclasses set `name` and implement `open_outputs` and `read_view`.

    All methods take the method config `cfg` (conf/method/<name>.yaml as a mapping).
    """

    name = ""
    forbidden_path_words: tuple[str, ...] = ()  # data-path substrings that switch its loader
    # view splits whose maps the system's render command writes (train = the lattice views)
    rendered_splits: tuple[str, ...] = ("train", "test")

    # --- export -------------------------------------------------------------------------
    def export(self, scene_dir: str | Path, out_dir: str | Path, cfg: Mapping) -> Path:
        """Write the scene in the input layout the system reads; returns the folder."""
        check_path_free_of(Path(out_dir), self.forbidden_path_words, self.name)
        return export_blender_scene(Path(scene_dir), Path(out_dir))

    # --- commands -----------------------------------------------------------------------
    def template_fields(self, cfg: dict) -> dict[str, str]:
        """Values of the `{placeholders}` of the command templates besides data/model/python."""
        return {}

    def commands(self, scene_export_dir: str | Path, model_dir: str | Path,
                 cfg: Mapping) -> list[list[str]]:
        """The argv lists that train the system and render its test views (run in `checkout`).

        Each template of `cfg["commands"]` is split like a shell line first, then every token
        is formatted with {python}, {data}, {model} and `template_fields`; a token that formats
        to "" (an option switched off) is dropped, and a token with spaces stays one argument.
        """
        cfg = as_dict(cfg)
        fields = {"python": str(cfg.get("python", "python")),
                  "data": str(Path(scene_export_dir).resolve()),
                  "model": str(Path(model_dir).resolve()), **self.template_fields(cfg)}
        out = []
        for template in option(cfg, "commands"):
            argv = []
            for token in shlex.split(template):
                try:
                    value = token.format(**fields)
                except KeyError as exc:
                    raise AdapterError(f"method {self.name}: command template {template!r} "
                                       f"uses unknown placeholder {exc}") from exc
                if value:
                    argv.append(value)
            out.append(argv)
        command_stages(cfg, len(out))  # a bad `command_stages` fails before anything runs
        return out

    def run(self, scene_export_dir: str | Path, model_dir: str | Path, cfg: Mapping, *,
            dry_run: bool = True, echo=print) -> float | None:
        """Print the commands; unless `dry_run`, run them in the checkout and time them.

        Returns:
            The wall time in seconds of all commands, or None for a dry run. Each command is
            timed; `<model_dir>/gspi_runtime.json` keeps the times and, with the config's
            `command_stages`, the geometry / material / end-to-end split (baselines/runtime.py).
        Raises:
            AdapterError: not a dry run and `checkout` is unset or missing.
            subprocess.CalledProcessError: a command failed.
        """
        cfg = as_dict(cfg)
        argvs = self.commands(scene_export_dir, model_dir, cfg)
        checkout = cfg.get("checkout")
        for argv in argvs:
            echo(f"(cd {checkout or '<checkout>'} && {shlex.join(argv)})")
        if dry_run:
            return None
        if not checkout or not Path(checkout).is_dir():
            raise AdapterError(f"method {self.name}: checkout={checkout!r} is not a folder; set "
                               f"method.checkout to a clone of {cfg.get('repo', {}).get('url')}")
        stages = command_stages(cfg, len(argvs))
        Path(model_dir).mkdir(parents=True, exist_ok=True)
        seconds = []
        for argv in argvs:
            start = time.perf_counter()
            subprocess.run(argv, cwd=checkout, check=True)
            seconds.append(time.perf_counter() - start)
        write_json_atomic(Path(model_dir) / RUNTIME_FILE, {
            "system": self.name, "seconds": sum(seconds), "commands": argvs, "command_seconds": seconds,
            "command_stages": stages, **split_seconds(seconds, stages)})
        return sum(seconds)

    # --- import -------------------------------------------------------------------------
    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> Any:
        """Locate and validate the system's output folder of the `split` views (`test`, or
        `train`: the lattice views); returns what `read_view` needs."""
        raise NotImplementedError

    def read_view(self, outputs: Any, index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        """Maps of the `index`-th view of `view.split`: {"albedo": HxWx3 sRGB-encoded,
        "roughness": HxW, "metallic": HxW (linear)}, only the channels the system models,
        values in [0, 1]; plus "alpha": HxW, the system's rendered opacity, where it saves it
        (written as the view's `alpha.png`, read by `eval.unpremultiply`)."""
        raise NotImplementedError

    def import_outputs(self, src: str | Path, scene_dir: str | Path, out_pred_dir: str | Path,
                       cfg: Mapping, runtime_s: float | Mapping | None = None, split: str = "test") -> Path:
        """Convert the system's outputs for one scene into `<out_pred_dir>/<scene name>/<split>/`.

        View k of the scene's `split` (its order in scene.json) is the system's view index k
        of that split (`test`, or `train`: the lattice views, exported as the training frames).
        Runtime: `runtime_s`, else `cfg["runtime_s"]` (a number = the total; or {geometry,
        material}), else `<src>/gspi_runtime.json` (a timed `run`, split by the config's
        `command_stages` where the system has them), else unknown; meta.json records
        `runtime_s.{geometry, material, end_to_end}` (baselines/runtime.py).

        Returns:
            The prediction folder of the scene.
        """
        cfg = as_dict(cfg)
        src, scene = Path(src), read_scene(scene_dir)
        if not src.is_dir():
            raise AdapterError(f"{src}: output folder of {self.name} not found")
        if split not in self.rendered_splits:
            raise AdapterError(f"{self.name}: its commands render the {' and '.join(self.rendered_splits)} "
                               f"views only, not {split!r}")
        outputs = self.open_outputs(src, scene, cfg, split)
        out_scene = Path(out_pred_dir) / scene.name
        for index, view in enumerate(scene.split_views(split)):
            maps = self.read_view(outputs, index, view, scene, cfg)
            alpha = maps.pop("alpha", None)  # the system's opacity, for eval.unpremultiply
            if alpha is not None:
                check_map(alpha, "roughness", scene, f"{src} ({self.name}, alpha of {split} view {index})")
                write_view_file(out_scene / split / view.id, "alpha.png", alpha[..., None])
            for channel, values in maps.items():
                check_map(values, channel, scene, f"{src} ({self.name}, {split} view {index} "
                                                  f"= {view.id})")
                write_material(out_scene / split / view.id, channel, values)
        given = runtime_s if runtime_s is not None else cfg.get("runtime_s")
        runtime = given_runtime(given) if given is not None else read_runtime(src, RUNTIME_FILE)
        runtime = runtime or {"geometry": None, "material": None, "end_to_end": None}
        write_meta(out_scene, method=str(cfg.get("name", self.name)), material_s=runtime["material"],
                   end_to_end_s=runtime["end_to_end"], geometry_s=runtime["geometry"],
                   source={"system": self.name, "outputs": str(src)})
        return out_scene


def check_map(values: np.ndarray, channel: str, scene: Scene, where: str) -> None:
    """A map must match the scene's image size and the channel's number of channels."""
    if channel not in MATERIAL_CHANNELS:
        raise ValueError(f"unknown channel {channel!r}; allowed: {MATERIAL_CHANNELS}")
    want = (scene.height, scene.width) + ((3,) if channel == "albedo" else ())
    if values.shape != want:
        raise AdapterError(f"{where}: {channel} map has shape {values.shape}, expected {want} "
                           "(rendered at another resolution?)")


# ----------------------------------------------------------------------------- registry

def systems() -> list[str]:
    """Names of the external systems: the conf/method/<name>.yaml files that name an ``adapter``."""
    from omegaconf import OmegaConf

    return sorted(p.stem for p in METHOD_CONF_DIR.glob("*.yaml") if OmegaConf.load(p).get("adapter"))


def load_method_config(name: str) -> dict:
    """conf/method/<name>.yaml of an external system as a plain dict (the recipe defaults)."""
    from omegaconf import OmegaConf

    path = METHOD_CONF_DIR / f"{name}.yaml"
    cfg = OmegaConf.to_container(OmegaConf.load(path), resolve=True) if path.is_file() else {}
    if not cfg.get("adapter"):
        raise ValueError(f"unknown system {name!r}; allowed: {', '.join(systems())}")
    return cfg


def get_adapter(name: str) -> Adapter:
    """The adapter of system `name`: the class its conf/method/<name>.yaml names as ``adapter``."""
    module, _, cls = str(load_method_config(name)["adapter"]).rpartition(".")
    return getattr(importlib.import_module(module), cls)()


def import_placed_outputs(cfg: Mapping, scene_dir: str | Path, out_pred_dir: str | Path,
                          split: str = "test") -> Path:
    """Table 1: import `<cfg.outputs>/<scene name>/` (the system's model dir for that scene),
    the views of `split` (`test`, or `train`: the lattice views).

    Raises:
        AdapterError: `outputs` is unset or has no folder for this scene.
    """
    cfg = as_dict(cfg)
    scene = read_scene(scene_dir)
    if not cfg.get("outputs"):
        raise AdapterError(f"method {cfg.get('name')}: set method.outputs=<folder> holding "
                           "<scene name>/ = the system's output dir of each scene")
    src = Path(cfg["outputs"]) / scene.name
    if not src.is_dir():
        raise AdapterError(f"{src}: missing (outputs of {cfg.get('name')} for scene {scene.name})")
    return get_adapter(str(cfg["name"])).import_outputs(src, scene_dir, out_pred_dir, cfg, split=split)
