"""In-house baseline "no decomposition": the observed colour is the albedo.

What a 2DGS asset gives without any material estimation: at each test view the asset's
rendered RGB (SH colour, i.e. the radiance the asset reproduces from the input photos, with
the capture lighting baked in) is taken as the base colour; roughness and metallic are two
constants, the mean ground truth over the foreground of the TRAINING scenes (the best
constant a method could learn from the training split, for the L2 error). The held-out
test photographs are not inputs: only the asset is.

Encodings: the rendered colour is un-premultiplied (composited colour / alpha, so partial
coverage at the silhouette does not darken it), clamped to [0, 1] and sRGB-encoded
(``eval.common.colorspace.linear_to_srgb``), as albedo.png stores it. Inside the rendered
silhouette (``alpha > silhouette_alpha``) the maps hold those values, outside 0.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Mapping

import numpy as np
import torch

from eval.common.colorspace import linear_to_srgb
from eval.common.layout import LayoutError, Scene, read_scene, read_splits, read_view_file, write_material
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.rasterize import render_gaussians

__all__ = ["fit_constants", "predict_scene", "observed_albedo"]

DEFAULT_SILHOUETTE_ALPHA = 0.004  # ~1/255: any composited surfel


def _scene_sums(scene_dir: Path) -> tuple[float, float, int]:
    """(sum of roughness, sum of metallic, foreground pixel count) over the lattice views.

    Reads ``gt_points.npz`` (one point per foreground pixel of the ``train`` views) when
    present, else the ``train`` views' roughness.png / metallic.png inside mask.png.
    """
    points = scene_dir / "gt_points.npz"
    if points.is_file():
        with np.load(points) as data:
            for key in ("roughness", "metallic"):
                if key not in data:
                    raise LayoutError(f"{points}: missing array {key!r}")
            r, m = data["roughness"].astype(np.float64), data["metallic"].astype(np.float64)
        return float(r.sum()), float(m.sum()), len(r)
    scene = read_scene(scene_dir)
    r_sum = m_sum = 0.0
    count = 0
    for v in scene.split_views("train"):
        d = scene.view_dir("train", v.id)
        mask = read_view_file(d, "mask.png")[..., 0] > 0.5
        r_sum += float(read_view_file(d, "roughness.png")[..., 0][mask].astype(np.float64).sum())
        m_sum += float(read_view_file(d, "metallic.png")[..., 0][mask].astype(np.float64).sum())
        count += int(mask.sum())
    return r_sum, m_sum, count


def fit_constants(data_dir: Path) -> dict[str, float]:
    """Mean GT roughness and metallic over the foreground pixels of the training scenes.

    Args:
        data_dir: Dataset folder with ``splits.json``; its ``train`` scenes are read.

    Returns:
        ``{"roughness": r, "metallic": m}``, pixel-weighted means over all training scenes.

    Raises:
        LayoutError: no training scenes, or a scene with no foreground pixel / missing file.
    """
    data_dir = Path(data_dir)
    names = read_splits(data_dir).get("train", [])
    if not names:
        raise LayoutError(f"{data_dir / 'splits.json'}: no 'train' scenes to fit the constants on")
    r_sum = m_sum = 0.0
    count = 0
    for name in names:
        r, m, n = _scene_sums(data_dir / name)
        r_sum, m_sum, count = r_sum + r, m_sum + m, count + n
    if count == 0:
        raise LayoutError(f"{data_dir}: the training scenes have no foreground pixel")
    return {"roughness": r_sum / count, "metallic": m_sum / count}


def prepare(cfg: Mapping, data_dir: Path) -> tuple[dict, dict]:
    """Per-run set-up for the runner: the constants, fitted once on the training split.

    Args:
        cfg: ``conf/method/no_decomposition.yaml`` contents (``fallback_constants``).
        data_dir: The run's dataset folder.

    Returns:
        ``(keyword arguments of predict_scene, what the run record keeps)``. Without training
        scenes, ``cfg["fallback_constants"]`` when set (else :func:`fit_constants` raises).
    """
    data_dir = Path(data_dir)
    has_train = (data_dir / "splits.json").is_file() and read_splits(data_dir).get("train")
    if has_train or not cfg.get("fallback_constants"):
        constants = fit_constants(data_dir)
        return {"constants": constants}, {"constants": constants, "constants_source": "fitted on the training split"}
    constants = {k: float(v) for k, v in cfg["fallback_constants"].items()}
    return {"constants": constants}, {"constants": constants,
                                      "constants_source": "method.fallback_constants (the dataset has no training scenes)"}


def observed_albedo(asset: Gaussians2D, w2c: np.ndarray, K: np.ndarray, width: int, height: int,
                    *, silhouette_alpha: float = DEFAULT_SILHOUETTE_ALPHA) -> tuple[torch.Tensor, torch.Tensor]:
    """The asset's colour at one camera as an albedo map.

    Args:
        asset: 2DGS surfels (SH colour).
        w2c: [4, 4] world-to-camera (OpenCV); K: [3, 3] pixel intrinsics.
        width, height: Image size in pixels.
        silhouette_alpha: Pixels with accumulated opacity above it are the object.

    Returns:
        ``(albedo_srgb [H, W, 3] in [0, 1], silhouette [H, W] bool)``, on the asset's device;
        albedo is 0 outside.
    """
    viewmat = torch.as_tensor(w2c, dtype=torch.float32, device=asset.means.device)[None]
    Ks = torch.as_tensor(K, dtype=torch.float32, device=asset.means.device)[None]
    with torch.no_grad():
        out = render_gaussians(asset, viewmat, Ks, width, height)
    alpha = out.alpha[0]
    inside = alpha > silhouette_alpha
    rgb = torch.where(inside, out.rgb[0] / alpha.clamp_min(1e-8), 0.0)
    return linear_to_srgb(rgb.clamp(0.0, 1.0)), inside[..., 0]


def predict_scene(scene: Scene, asset: Gaussians2D, out_scene_dir: Path, cfg: Mapping, *,
                  constants: dict[str, float], split: str = "test", progress: bool = False,
                  device: torch.device | str = "cpu") -> dict:
    """Writes ``<out_scene_dir>/<split>/<view id>/{albedo,roughness,metallic}.png``.

    Args:
        scene: The ground-truth scene (only the cameras of its ``split`` views are read).
        asset: The scene's 2DGS asset.
        out_scene_dir: ``<pred>/<scene name>``.
        cfg: ``conf/method/no_decomposition.yaml`` contents (``silhouette_alpha``).
        constants: :func:`fit_constants` output.
        split: The views written: ``test`` (held-out) or ``train`` (the lattice views).
        progress: Unused (the method is a few renders); kept for the runner's interface.
        device: Where the asset is rendered (the run's ``device``); maps are written from the CPU.

    Returns:
        ``{"material_s": wall seconds, "material_cpu_s": process CPU seconds,
        "test_views": count, "roughness": r, "metallic": m}``.
    """
    for key in ("roughness", "metallic"):
        if key not in constants:
            raise ValueError(f"constants must hold 'roughness' and 'metallic', got {sorted(constants)}")
    silhouette_alpha = float(dict(cfg or {}).get("silhouette_alpha", DEFAULT_SILHOUETTE_ALPHA))
    t0, cpu0 = time.perf_counter(), time.process_time()
    views, asset = scene.split_views(split), asset.to(device)
    for v in views:
        albedo, inside = observed_albedo(asset, v.w2c, v.K, scene.width, scene.height,
                                         silhouette_alpha=silhouette_alpha)
        vdir = Path(out_scene_dir) / split / v.id
        write_material(vdir, "albedo", albedo.cpu().numpy())
        for key in ("roughness", "metallic"):
            write_material(vdir, key, np.where(inside.cpu().numpy(), constants[key], 0.0)[..., None])
    return {"material_s": time.perf_counter() - t0, "material_cpu_s": time.process_time() - cpu0,
            "test_views": len(views),
            "roughness": constants["roughness"], "metallic": constants["metallic"]}
