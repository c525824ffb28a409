"""The images of one scene view: ground truth and every method, with error maps and scores.

Relit images are the evaluator's: `eval.views.relight_view` with ground-truth normals, the
predicted maps (albedo aligned as the job's protocol says, unmodelled roughness/metallic
filled with the protocol's constants) and the protocol's display transform, so the PSNR,
SSIM and LPIPS printed under a panel (read from the job's `per_view.csv`, never recomputed)
are those of exactly that image. Ground-truth relit images are `relit_<env>.exr` when the
scene has them (bit-exact with the shader, docs/FORMAT.md), else shaded from the GT maps.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from omegaconf import OmegaConf

from eval.config import RelightConfig
from eval.evaluate import EnvironmentCache
from eval.imageio import read_exr
from eval.layout import MATERIAL_CHANNELS, LayoutError, Scene, material_file, read_view_file
from eval.protocol import apply_albedo_scale, display_relit, fit_albedo_scale
from eval.report_site.collect import Job
from eval.views import relight_view, view_directions

ERROR_MAX = 0.5   # error maps: |pred - gt| (mean over colour channels) from 0 to this, clipped


@dataclass
class Panel:
    """One tile: an image in display values [0, 1] or None (then `note` says why)."""

    image: np.ndarray | None = None    # [H, W, 3]
    error: np.ndarray | None = None    # [H, W] |pred - gt| in display units
    metrics: dict | None = None        # psnr, ssim, lpips of per_view.csv
    note: str = ""


@dataclass
class ViewPanels:
    """Ground truth and every job's panels of one view; keys: channel or "relit:<env>"."""

    view: str
    gt: dict[str, np.ndarray]
    jobs: dict[str, dict[str, Panel]] = field(default_factory=dict)   # job label -> key -> Panel


def relight_config(protocol: dict) -> RelightConfig:
    """The job's relight protocol (eval_meta.json protocol_config.relight), defaults filled."""
    base = OmegaConf.structured(RelightConfig)
    return OmegaConf.merge(base, protocol.get("relight") or {})


def _t(arr: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(arr))


def _rgb(arr: np.ndarray) -> np.ndarray:
    return np.repeat(arr, 3, axis=-1) if arr.shape[-1] == 1 else arr


def _error(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return np.where(mask, np.abs(_rgb(pred) - _rgb(gt)).mean(axis=-1), 0.0)


def _metrics(frame: pd.DataFrame, scene: str, view: str, channel: str, env: str = "") -> dict | None:
    if frame.empty:
        return None
    sel = frame[(frame["scene"] == scene) & (frame["view"] == view)
                & (frame["channel"] == channel) & (frame["env"] == env)]
    if sel.empty:
        return None
    return {m: float(sel.iloc[0][m]) for m in ("psnr", "ssim", "lpips")}


class SceneRenderer:
    """Builds `ViewPanels` for the views of one scene; prefiltered environments are shared."""

    def __init__(self, scene: Scene, envs: list[str], split: str = "test"):
        self.scene, self.env_names, self.split = scene, envs, split
        self.cache = EnvironmentCache()

    def environment(self, name: str):
        return self.cache.get(self.scene.envmap_path(name))

    def gt_view(self, view) -> dict:
        vdir = self.scene.view_dir(self.split, view.id)
        gt = {c: read_view_file(vdir, material_file(c)) for c in MATERIAL_CHANNELS}
        gt["normal"] = read_view_file(vdir, "normal.exr")
        gt["mask"] = read_view_file(vdir, "mask.png")[..., 0] > 0.5
        gt["view_dir"] = view_directions(view.K, view.w2c, self.scene.height, self.scene.width)
        return gt

    def gt_relit(self, view, gt: dict, env: str, cfg) -> np.ndarray:
        path = self.scene.view_dir(self.split, view.id) / f"relit_{env}.exr"
        if path.is_file():
            radiance = _t(read_exr(path))
        else:
            radiance = relight_view(_t(gt["albedo"]), _t(gt["roughness"]), _t(gt["metallic"]),
                                    _t(gt["normal"]), gt["view_dir"], self.environment(env))
        return display_relit(radiance, cfg).numpy()


def load_predictions(scene: Scene, pred_dir: Path, split: str) -> dict[str, dict[str, np.ndarray]]:
    """view id -> {channel: map} for the files present (a bad file raises LayoutError)."""
    out = {}
    for view in scene.split_views(split):
        vdir = pred_dir / split / view.id
        out[view.id] = {c: read_view_file(vdir, material_file(c)) for c in MATERIAL_CHANNELS
                        if (vdir / material_file(c)).is_file()}
        for c, arr in out[view.id].items():
            if arr.shape[:2] != (scene.height, scene.width):
                raise LayoutError(f"{vdir / material_file(c)}: size {arr.shape[:2]} != ground "
                                  f"truth {(scene.height, scene.width)}")
    return out


def albedo_scales(scene: Scene, preds: dict, gts: dict, protocol: dict) -> dict[str, torch.Tensor]:
    """view id -> linear albedo scale, as gspi-eval fits it (scene or view scope)."""
    mode = protocol.get("albedo_alignment", "none")
    have = [v for v in preds if "albedo" in preds[v]]

    def fit(ids):
        return fit_albedo_scale([_t(preds[i]["albedo"]) for i in ids],
                                [_t(gts[i]["albedo"]) for i in ids],
                                [_t(gts[i]["mask"]) for i in ids], mode)

    if not have or mode == "none":
        return {v: torch.ones(3, dtype=torch.float64) for v in have}
    if protocol.get("alignment_scope", "scene") == "scene":
        scale = fit(have)
        return {v: scale for v in have}
    return {v: fit([v]) for v in have}


def job_panels(renderer: SceneRenderer, job: Job, views: list, gts: dict, per_view: pd.DataFrame
               ) -> dict[str, dict[str, Panel]]:
    """view id -> key -> Panel for one job; every failure becomes a note, never an exception."""
    scene, keys = renderer.scene, list(MATERIAL_CHANNELS) + [f"relit:{e}" for e in renderer.env_names]
    pred_dir = job.prediction(scene.name)
    if pred_dir is None:
        why = job.scene_errors.get(scene.name)
        note = f"missing: {why}" if why else "missing: no prediction for this scene"
        return {v.id: {k: Panel(note=note) for k in keys} for v in views}
    try:
        preds = load_predictions(scene, pred_dir, renderer.split)
    except LayoutError as exc:
        return {v.id: {k: Panel(note=f"unreadable: {exc}") for k in keys} for v in views}
    modelled = {c for p in preds.values() for c in p}
    scales = albedo_scales(scene, preds, gts, job.protocol)
    cfg = relight_config(job.protocol)
    out = {}
    for view in views:
        gt, pred = gts[view.id], dict(preds[view.id])
        if "albedo" in pred and cfg.apply_albedo_alignment:
            pred["albedo"] = apply_albedo_scale(_t(pred["albedo"]), scales[view.id]).numpy()
        panels = {}
        for c in MATERIAL_CHANNELS:
            if c in pred:
                panels[c] = Panel(_rgb(pred[c]), _error(pred[c], gt[c], gt["mask"]),
                                  _metrics(per_view, scene.name, view.id, c))
            else:
                panels[c] = Panel(note="not modelled" if c not in modelled else "missing view")
        for env in renderer.env_names:
            panels[f"relit:{env}"] = _relit_panel(renderer, view, gt, pred, modelled, env, cfg,
                                                  per_view)
        out[view.id] = panels
    return out


def _relit_panel(renderer, view, gt, pred, modelled, env, cfg, per_view) -> Panel:
    if "albedo" not in pred or any(c not in pred for c in modelled):
        return Panel(note="no relit image (no albedo)" if "albedo" not in modelled
                     else "missing view")
    h, w = gt["mask"].shape
    rough = pred.get("roughness", np.full((h, w, 1), float(cfg.fill_roughness), np.float32))
    metal = pred.get("metallic", np.full((h, w, 1), float(cfg.fill_metallic), np.float32))
    radiance = relight_view(_t(pred["albedo"]), _t(rough), _t(metal), _t(gt["normal"]),
                            gt["view_dir"], renderer.environment(env))
    image = display_relit(radiance, cfg).numpy()
    return Panel(image, _error(image, gt[f"relit:{env}"], gt["mask"]),
                 _metrics(per_view, renderer.scene.name, view.id, "relight", env))


def scene_panels(scene: Scene, jobs: list[Job], per_view: dict[str, pd.DataFrame], *,
                 split: str = "test", max_views: int | None = None) -> tuple[list[ViewPanels], list[str]]:
    """Panels of the first `max_views` views of `scene` for every job; and the environments."""
    protocol = next((j.protocol for j in jobs if j.protocol), {})
    envs = list((protocol.get("relight") or {}).get("envs") or scene.relight_envs)
    renderer = SceneRenderer(scene, envs, split)
    views = scene.split_views(split)[:max_views]
    cfg = relight_config(protocol)
    gts = {}
    for view in views:
        gt = renderer.gt_view(view)
        for env in envs:
            gt[f"relit:{env}"] = renderer.gt_relit(view, gt, env, cfg)
        gts[view.id] = gt
    all_gts = {v.id: gts.get(v.id) or renderer.gt_view(v) for v in scene.split_views(split)}
    panels = [ViewPanels(v.id, {k: (_rgb(a) if k not in ("normal", "mask", "view_dir") else a)
                                for k, a in gts[v.id].items()}) for v in views]
    keys = list(MATERIAL_CHANNELS) + [f"relit:{e}" for e in envs]
    for job in jobs:
        try:
            by_view = job_panels(renderer, job, views, all_gts,
                                 per_view.get(job.label, pd.DataFrame()))
        except (LayoutError, ValueError, RuntimeError) as exc:  # one bad job, not a bad page
            by_view = {v.id: {k: Panel(note=f"unreadable: {exc}") for k in keys} for v in views}
        for vp in panels:
            vp.jobs[job.label] = by_view[vp.view]
    return panels, envs
