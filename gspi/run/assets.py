"""The 2DGS asset of each scene: given by the user, or reconstructed once and reused.

``assets=<file.ply>`` (one scene), ``assets=<dir>`` holding ``<dir>/<scene>/point_cloud.ply``
or ``<dir>/<scene>.ply`` (e.g. the output folders of gspi-recon or the official 2DGS code),
or ``assets=null``: Stage 0 (gspi/recon) fits the scene's ``train`` views, and the result is
cached at ``<cache>/recon/<hash of the recon config>/<scene>/point_cloud.ply`` so every job
of a sweep (every method, every ablation) starts from the SAME asset, as in the paper.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Mapping, Optional

import numpy as np
import torch

from eval.common.atomic import atomic_path
from eval.common.errors import StatedError
from eval.common.layout import MATERIAL_CHANNELS, Scene, material_file, read_view_file
from eval.common.atomic import write_json_atomic
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.ply import read_asset_ply, read_ply, write_ply
from gspi.run.locks import file_lock
from gspi.run.record import config_hash
from gspi.strict_config import dataclass_from_dict

log = logging.getLogger(__name__)


class AssetError(StatedError, FileNotFoundError):
    """The asset a run was given cannot be found or read, or does not cover its scene."""


@dataclass(frozen=True)
class AssetCheckConfig:
    """gspi-run's ``asset_check`` (conf/gspi_run.yaml): a user asset against the scene's photos."""

    min_psnr: float = 10.0   # dB, masked display PSNR at the train views; below: a warning (docs/RELIABILITY.md)
    strict: bool = False     # below min_psnr is an error

    RANGES: ClassVar[dict] = {"min_psnr": (0.0, 200.0)}

    @classmethod
    def from_dict(cls, data: Optional[Mapping[str, Any]]) -> "AssetCheckConfig":
        return dataclass_from_dict(cls, dict(data or {}), "asset_check")


MIN_VISIBLE = 0.5     # fraction of surfel centres that must project into some view of the scene
MIN_COVERAGE = 0.01   # fraction of the ground-truth foreground a prediction must not leave black


def check_asset_covers_scene(gaussians: Gaussians2D, scene: Scene, source: str) -> dict:
    """Refuses an asset that cannot depict ``scene``: no surfels, surfel centres outside every
    camera of scene.json (an asset in another frame or 1e6 units away), or surfels larger than
    the camera rig (huge scales). Such an asset would otherwise run to "complete" with black
    maps. Returns {"visible_fraction", "median_scale", "rig_radius"} for the run's record.

    Raises:
        AssetError: naming ``source`` (the PLY or the reconstruction) and the measured values.
    """
    n = gaussians.num_gaussians
    if n == 0:
        raise AssetError(f"{source}: the 2DGS asset has no surfels (empty vertex element)")
    means = gaussians.means.detach().double().cpu().numpy()  # [N, 3]
    views = [v for vs in scene.views.values() for v in vs]
    visible = np.zeros(n, dtype=bool)
    centres = []
    for v in views:
        cam = means @ v.w2c[:3, :3].T + v.w2c[:3, 3]
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (cam @ v.K.T)[:, :2] / z[:, None]
        visible |= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < scene.width) & (uv[:, 1] >= 0) & (uv[:, 1] < scene.height)
        centres.append(v.camera_center)
    centres = np.asarray(centres)
    rig_radius = float(np.median(np.linalg.norm(centres - centres.mean(0), axis=1))) or 1.0
    median_scale = float(torch.exp(gaussians.log_scales.detach().double()).max(dim=1).values.median())
    fraction = float(visible.mean())
    info = {"visible_fraction": round(fraction, 4), "median_scale": median_scale, "rig_radius": rig_radius}
    if fraction < MIN_VISIBLE:
        centroid = means.mean(0).round(3).tolist()
        raise AssetError(f"{source}: only {100 * fraction:.1f}% of the asset's {n} surfel centres lie in "
                         f"any camera view of {scene.root / 'scene.json'} (need {100 * MIN_VISIBLE:.0f}%; "
                         f"their centroid is {centroid}): the asset is not in the scene's frame")
    if not median_scale < rig_radius:
        raise AssetError(f"{source}: median surfel size {median_scale:.3g} is not below the camera rig "
                         f"radius {rig_radius:.3g} of {scene.root / 'scene.json'} (scales in the wrong "
                         "units, or log scales stored as plain values?)")
    return info


def check_asset_matches_photos(gaussians: Gaussians2D, scene: Scene, source: str, *, display_cfg,
                               check: AssetCheckConfig, split: str = "train") -> dict:
    """A user's asset rendered at ``scene``'s input views against the captured images: masked
    display PSNR per view (``gspi.recon.trainer.evaluate_views``, Stage 0's record measure).
    Below ``check.min_psnr`` the asset may not depict this scene (another object, other
    lighting, an unlit export): one warning line, or with ``check.strict`` an
    :class:`AssetError`. Returns the record's ``asset_check`` entry."""
    from gspi.recon.data import load_scene_views
    from gspi.recon.trainer import evaluate_views

    metrics = evaluate_views(gaussians, load_scene_views(scene, split), display_cfg)
    psnr = metrics["psnr_masked"]
    info = {"split": split, "views": metrics["num_views"], "psnr_masked": psnr,
            "psnr_masked_min": min((v["psnr_masked"] for v in metrics["per_view"]), default=None),
            "alpha_iou": metrics["alpha_iou"], "min_psnr": float(check.min_psnr),
            "passed": psnr is None or psnr >= check.min_psnr}
    if not info["passed"]:
        message = (f"{source}: its renders of the {metrics['num_views']} {split} views of {scene.name} score "
                   f"{psnr:.2f} dB masked display PSNR against the photos (asset_check.min_psnr={check.min_psnr:g}): "
                   f"the asset may not depict this scene")
        if check.strict:
            raise AssetError(message + " (asset_check.strict=true)")
        log.warning("%s", message)
        info["warning"] = message
    return info


def check_prediction_covers_scene(scene: Scene, pred_scene: Path, split: str) -> float:
    """The fraction of ground-truth foreground pixels (over the split's views) where the
    prediction has any non-zero material value. Raises when it is below MIN_COVERAGE: maps that
    are black wherever the object is are a failed run, not a score. Views or channels the
    method did not write are left to the evaluator (missing, not black)."""
    covered = total = 0
    for v in scene.split_views(split):
        pdir = pred_scene / split / v.id
        maps = [read_view_file(pdir, material_file(c), (scene.height, scene.width))
                for c in MATERIAL_CHANNELS if (pdir / material_file(c)).is_file()]
        mask_path = scene.view_dir(split, v.id) / "mask.png"
        if not maps or not mask_path.is_file():
            continue
        mask = read_view_file(mask_path.parent, "mask.png")[..., 0] > 0.5
        lit = np.zeros(mask.shape, dtype=bool)
        for m in maps:
            lit |= (m > 0).any(axis=-1)
        covered, total = covered + int((lit & mask).sum()), total + int(mask.sum())
    fraction = covered / total if total else 1.0
    if fraction < MIN_COVERAGE:
        raise AssetError(f"{pred_scene}: the predicted maps are black on {100 * (1 - fraction):.1f}% of "
                         f"the ground-truth foreground of the {split} views (the asset does not "
                         "cover the scene; check its position and scale)")
    return fraction


def read_user_asset(path: Path) -> tuple[Gaussians2D, dict]:
    """``read_asset_ply`` (2DGS, or 3DGS flattened to surfels) with every failure an
    :class:`AssetError` naming ``path``."""
    try:
        return read_asset_ply(path)
    except StatedError as exc:  # already names the file
        raise AssetError(str(exc)) from exc
    except Exception as exc:
        raise AssetError(f"{path}: cannot read the Gaussian asset ({type(exc).__name__}: {exc})") from exc


def check_user_assets(assets: Optional[str]) -> None:
    """Before a run starts (gspi-run): ``assets=`` exists, and when it is one PLY, it reads.
    Raises :class:`AssetError` naming the path, so a bad file is one line, not a failed job."""
    from gspi.run.stage2_model import resolve_path

    if not assets:
        return
    root = resolve_path(assets)
    if not root.exists():
        raise AssetError(f"{root}: assets= not found (a 2DGS/3DGS .ply, or a folder of <scene>/point_cloud.ply)")
    if root.is_file():
        read_user_asset(root)


def user_asset_path(assets: str | Path, scene_name: str, num_scenes: int) -> Path:
    """The PLY of ``scene_name`` under ``assets`` (a file for one scene, or a folder; a relative
    path that does not exist from the working directory is read from the repository root, so
    the shipped demo assets ``checkpoints/demo_assets`` work from anywhere)."""
    from gspi.run.stage2_model import resolve_path

    root = resolve_path(assets)
    if root.is_file():
        if num_scenes != 1:
            raise AssetError(f"{root}: one PLY given for {num_scenes} scenes; pass a folder with "
                             f"<scene>/point_cloud.ply, or select one scene with scenes=[name]")
        return root
    candidates = [root / scene_name / "point_cloud.ply", root / f"{scene_name}.ply"]
    for path in candidates:
        if path.is_file():
            return path
    raise AssetError(f"{root}: no 2DGS asset for scene {scene_name!r} (looked for "
                     f"{', '.join(str(c) for c in candidates)})")


def cached_reconstruction(scene: Scene, recon_cfg: Mapping[str, Any], cache_root: Path, *,
                          device: str = "cpu") -> tuple[Gaussians2D, dict]:
    """Stage 0 (``gspi.recon.reconstruct``, gspi-recon's record) once per (scene, recon config),
    fitted to the ``train`` views with held-out metrics on ``test``; parallel jobs wait on a
    file lock."""
    from gspi.recon.reconstruct import reconstruct_scene

    folder = Path(cache_root) / "recon" / config_hash(dict(recon_cfg), volatile=("log_every",)) / scene.name
    ply = folder / "point_cloud.ply"
    with file_lock(folder):
        if ply.is_file():
            info = json.loads((folder / "recon.json").read_text()) if (folder / "recon.json").is_file() else {}
            return read_ply(ply), {**info, "cached": True, "path": str(ply)}
        gaussians, info = reconstruct_scene(scene, recon_cfg, device=device, eval_split="test")
        folder.mkdir(parents=True, exist_ok=True)
        write_json_atomic(folder / "recon.json", info)
        with atomic_path(ply) as tmp:  # the PLY last: its presence means the cache entry is whole
            write_ply(tmp, gaussians)
        return gaussians, {**info, "cached": False, "path": str(ply)}


def scene_asset(scene: Scene, *, assets: Optional[str], num_scenes: int, recon_cfg: Mapping[str, Any],
                cache_root: Path, device: str = "cpu", asset_check: Optional[Mapping[str, Any]] = None
                ) -> tuple[Gaussians2D, dict]:
    """(asset, info): info["source"] is "user" or "recon"; "seconds" is the reconstruction time
    (the cached run's time when reused, so end-to-end runtimes stay comparable)."""
    if assets:
        path = user_asset_path(assets, scene.name, num_scenes)
        gaussians, read_info = read_user_asset(path)
        coverage = check_asset_covers_scene(gaussians, scene, str(path))
        from gspi.recon.trainer import ReconConfig

        photos = check_asset_matches_photos(gaussians, scene, str(path),
                                            display_cfg=ReconConfig.from_dict(dict(recon_cfg)).display,
                                            check=AssetCheckConfig.from_dict(asset_check))
        return gaussians, {"source": "user", "path": str(path), "seconds": None, "coverage": coverage,
                           "asset_check": photos,
                           "asset_format": {k: v for k, v in read_info.items() if k != "path"}}
    gaussians, info = cached_reconstruction(scene, recon_cfg, cache_root, device=device)
    coverage = check_asset_covers_scene(gaussians, scene, f"reconstruction {info.get('path')}")
    return gaussians, {"source": "recon", **info, "coverage": coverage}
