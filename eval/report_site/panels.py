"""The images of one scene view: ground truth and every method, with error maps and scores.

A job's panels are the views as its protocol scored them (`eval.scored_view`: the scored,
eroded mask, the aligned albedo, the relit images after the scale fit and the display
transform), so the PSNR, SSIM and LPIPS printed under a panel (read from the job's
`per_view.csv`, never recomputed) are those of exactly that image; error maps are taken
inside the scored mask. Ground-truth relit images are `relit_<env>.exr` when the
scene has them (bit-exact with the shader, docs/FORMAT.md), else shaded from the GT maps.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch
from omegaconf import OmegaConf

from eval.config import RelightConfig
from eval.common.imageio import read_exr
from eval.common.layout import MATERIAL_CHANNELS, LayoutError, Scene, material_file, read_view_file
from eval.protocol import display_relit
from eval.report_site.collect import Job
from eval.scored_view import EnvironmentCache, scene_scored_views
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

    def __init__(self, scene: Scene, envs: list[str], split: str = "test",
                 cache: EnvironmentCache | None = None):
        self.scene, self.env_names, self.split = scene, envs, split
        self.cache = EnvironmentCache() if cache is None else cache  # the report's, shared by its scenes
        self.gt_cache: dict = {}  # the scored GT views, read once for all jobs

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


def protocol_config(protocol: dict):
    """The job's protocol (eval_meta.json protocol_config) as the scorer reads it, defaults filled."""
    from eval.config import ProtocolConfig

    return OmegaConf.merge(OmegaConf.structured(ProtocolConfig), protocol or {})


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float32)


def job_panels(renderer: SceneRenderer, job: Job, views: list, per_view: pd.DataFrame
               ) -> dict[str, dict[str, Panel]]:
    """view id -> key -> Panel for one job, from the views as the job's protocol scored them
    (``eval.scored_view``); every failure becomes a note, never an exception."""
    scene, keys = renderer.scene, list(MATERIAL_CHANNELS) + [f"relit:{e}" for e in renderer.env_names]
    pred_dir = job.prediction(scene.name)
    if pred_dir is None:
        why = job.scene_errors.get(scene.name)
        note = f"missing: {why}" if why else "missing: no prediction for this scene"
        return {v.id: {k: Panel(note=note) for k in keys} for v in views}
    try:
        scored, missing = scene_scored_views(scene, pred_dir, protocol_config(job.protocol), renderer.cache,
                                             views=views, gt_cache=renderer.gt_cache)
    except (LayoutError, ValueError) as exc:
        return {v.id: {k: Panel(note=f"unreadable: {exc}") for k in keys} for v in views}
    modelled = {c for sv in scored for c in sv.pred} | {m["channel"] for m in missing}
    by_id = {sv.view: sv for sv in scored}
    out = {}
    for view in views:
        sv = by_id.get(view.id)
        if sv is None:
            out[view.id] = {k: Panel(note="not a scored view of this job's protocol") for k in keys}
            continue
        mask = _np(sv.mask).astype(bool)
        panels = {}
        for c in MATERIAL_CHANNELS:
            if c in sv.pred:
                image, gt = _np(sv.pred[c]), _np(sv.gt[c])
                panels[c] = Panel(_rgb(image), _error(image, gt, mask), _metrics(per_view, scene.name, view.id, c))
            else:
                panels[c] = Panel(note="not modelled" if c not in modelled else "missing view")
        for env in renderer.env_names:
            pair = sv.relit.get(env)
            if pair is None:
                note = "no relit image (no albedo)" if "albedo" not in modelled else "missing view"
                panels[f"relit:{env}"] = Panel(note=note)
                continue
            image = _np(pair.pred)
            panels[f"relit:{env}"] = Panel(image, _error(image, _np(pair.gt), mask),
                                           _metrics(per_view, scene.name, view.id, "relight", env))
        out[view.id] = panels
    return out


def scene_panels(scene: Scene, jobs: list[Job], per_view: dict[str, pd.DataFrame], *,
                 split: str = "test", max_views: int | None = None,
                 env_cache: EnvironmentCache | None = None) -> tuple[list[ViewPanels], list[str]]:
    """Panels of the first `max_views` views of `scene` for every job; and the environments.
    ``env_cache``: prefiltered environments kept across scenes (a dataset's scenes share maps)."""
    protocol = next((j.protocol for j in jobs if j.protocol), {})
    envs = list((protocol.get("relight") or {}).get("envs") or scene.relight_envs)
    renderer = SceneRenderer(scene, envs, split, env_cache)
    views = scene.split_views(split)[:max_views]
    cfg = relight_config(protocol)
    gts = {}
    for view in views:
        gt = renderer.gt_view(view)
        for env in envs:
            gt[f"relit:{env}"] = renderer.gt_relit(view, gt, env, cfg)
        gts[view.id] = gt
    panels = [ViewPanels(v.id, {k: (_rgb(a) if k not in ("normal", "mask", "view_dir") else a)
                                for k, a in gts[v.id].items()}) for v in views]
    keys = list(MATERIAL_CHANNELS) + [f"relit:{e}" for e in envs]
    for job in jobs:
        try:
            by_view = job_panels(renderer, job, views, per_view.get(job.label, pd.DataFrame()))
        except (LayoutError, ValueError, RuntimeError) as exc:  # one bad job, not a bad page
            by_view = {v.id: {k: Panel(note=f"unreadable: {exc}") for k in keys} for v in views}
        for vp in panels:
            vp.jobs[job.label] = by_view[vp.view]
    return panels, envs
