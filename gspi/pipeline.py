"""GS-PI on one scene: 2DGS asset -> Stage I points -> Stage II PBR -> Stage III PBR-GS asset.

    asset --Stage I--> points + lattice renders (with their cameras)
          --Stage II (points, renders)--> per-point PBR
          --scatter into the renders' views--> staged targets --Stage III--> PBR-GS asset
          --render--> test-view maps

Each stage is one call into its package; this module only wires them, times them
(``StageClock``) and leaves the intermediate files in ``work_dir`` for inspection:
``points.npz`` (Stage I), ``points_pbr.npz`` (Stage II), ``stage1.json``, ``pbr_gs.ply``
(the relightable asset: 2DGS attributes + named material attributes), ``stage3.json``.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional

import numpy as np

from eval.common.layout import Scene
from eval.common.atomic import write_json_atomic
from gspi.gaussians.model import Gaussians2D

if TYPE_CHECKING:
    from gspi.stage1.config import Stage1Config
    from gspi.stage3.config import Stage3Config
from gspi.gaussians.ply import write_ply
from gspi.stage_clock import StageClock

log = logging.getLogger(__name__)


@dataclass
class Stage2Context:
    """What every scene of a run shares: the Stage II model, its training config (``stage2``
    a checked ``Stage2Config``), its encoder, and the run's own ``Stage2Config`` (whose
    ``inference`` section samples the clouds).

    Built by the caller (``gspi.run.stage2_model.load_stage2_context`` loads or trains it).
    """

    model: Any
    model_cfg: Mapping[str, Any]
    encoder: Any
    info: dict
    run_cfg: Any  # gspi.stage2.config.Stage2Config of the run

    @property
    def reads_photos(self) -> bool:
        """Whether the model's light read-out reads the scene's photos (``stage2.inference.light_views``)."""
        return bool(self.model_cfg["stage2"].data.light_readout) and self.run_cfg.inference.light_views == "photos"

    def predict(self, points, renders, device, photos=None, num_gaussians=None) -> tuple[np.ndarray, dict]:
        """[P, 5] PBR of a Stage I cloud (albedo sRGB, roughness, metallic) and stats; ``photos``:
        the scene's photos at the lattice cameras for the light read-out (``reads_photos``);
        ``num_gaussians``: the asset's (``stage2.inference.points_per_gaussian``)."""
        from gspi.stage2.infer import predict_generated_points

        data_cfg = self.model_cfg["stage2"].data
        light_table, light = None, None
        if data_cfg.light_readout:
            from gspi.stage2.light_fit import inference_light_table

            light_table, light = inference_light_table(points, renders, data_cfg, photos)
        pbr, stats = predict_generated_points(self.model, points, renders, data=data_cfg, encoder=self.encoder,
                                              cfg=self.run_cfg.inference.for_asset(num_gaussians),
                                              light_table=light_table, device=device)
        return pbr, (stats if light is None else {**stats, "light": light})


@dataclass
class LightFitContext:
    """``method=light_fit``'s materials in Stage II's place: the training-free read-out against the
    light estimated among ``candidates`` (``gspi.stage2.light_fit``)."""

    cfg: Any          # gspi.stage2.light_fit.LightFitConfig
    candidates: dict  # {name: eval.relight.PrefilteredEnvironment}

    @property
    def reads_photos(self) -> bool:
        return self.cfg.views == "photos"

    def predict(self, points, renders, device, photos=None, num_gaussians=None) -> tuple[np.ndarray, dict]:
        from gspi.stage2.light_fit import predict_light_fit

        return predict_light_fit(points, renders, self.cfg.for_asset(num_gaussians), self.candidates, photos)


def gt_reference(scene: Scene) -> Optional[np.ndarray]:
    """GT surface samples of a generated scene (for Stage I's filter report), else None."""
    path = scene.root / "gt_points.npz"
    if not path.is_file():
        return None
    with np.load(path) as npz:
        return npz["xyz"]


def run_gspi_scene(scene: Scene, asset: Gaussians2D, out_scene_dir: Path, cfg: Mapping[str, Any], *,
                   stage1: Stage1Config, stage2: Stage2Context | LightFitContext, stage3: Stage3Config, clock: StageClock,
                   work_dir: Path, split: str = "test", progress: bool = False) -> dict:
    """Runs Stages I-III on ``asset`` and writes the material maps of ``scene``'s ``split`` views.

    ``stage1``, ``stage2``, ``stage3``: the run's checked stage configs (and Stage II's model, or
    the light read-out in its place), built once per run by the method's ``prepare``; ``cfg`` is
    read for ``device`` only.

    Returns:
        {"stage1": report, "stage2": stats, "stage3": stats, "points_scores": Table 2's
        measure on the generated cloud (None when the lattice size differs from the scene's)}.
    """
    from gspi.stage1.extract import extract_point_cloud
    from gspi.stage3.distill import distill
    from gspi.stage3.export import write_scene_predictions
    from gspi.stage3.targets import stage_targets

    from gspi.device import resolve_device

    device = resolve_device(cfg.get("device", "cpu"))  # checked at start-up (check_run_config)
    if device.type != "cpu":  # Stages I and III render where the asset lives
        asset = asset.to(device)
    work_dir.mkdir(parents=True, exist_ok=True)
    s1cfg = stage1
    with clock.stage("stage1"):
        points, renders, s1 = extract_point_cloud(asset, s1cfg, reference=gt_reference(scene))
        points.save(work_dir / "points.npz")
    write_json_atomic(work_dir / "stage1.json", s1)

    with clock.stage("stage2"):
        photos, views = None, None
        if stage2.reads_photos:  # the light read from the photos, the asset for geometry (docs/LIGHT.md)
            from gspi.stage2.light_views import lattice_photos

            photos, views = lattice_photos(scene.root, renders)
        pbr, s2 = stage2.predict(points, renders, device, photos, num_gaussians=asset.num_gaussians)
        if views is not None:
            s2 = {**s2, "light": {**s2.get("light", {}), "views": views}}
        np.savez_compressed(work_dir / "points_pbr.npz", pbr=pbr)

    points_scores = None
    if not s1cfg.image_size == scene.width == scene.height:
        log.warning("%s: no Table 2 measure (points_eval): Stage I renders %d px, the scene is %dx%d; "
                    "set stage1.image_size=%d", scene.name, s1cfg.image_size, scene.height, scene.width, scene.width)
    else:
        from gspi.stage2.score_generated import score_generated_points

        with clock.stage("points_eval"):
            points_scores = score_generated_points(points, pbr, scene.root)

    s3cfg = stage3
    with clock.stage("stage3"):
        targets = stage_targets(points, pbr, renders, alpha_threshold=s1cfg.alpha_threshold)
        pbr_asset, s3 = distill(asset, targets, s3cfg, progress=progress)
        write_ply(work_dir / "pbr_gs.ply", pbr_asset)
    write_json_atomic(work_dir / "stage3.json", _jsonable(s3))
    with clock.stage("render"):
        write_scene_predictions(pbr_asset, scene, out_scene_dir, split=split)
    return {"stage1": {k: v for k, v in s1.items() if k != "config"}, "stage2": s2,
            "stage3": {k: v for k, v in _jsonable(s3).items() if not isinstance(v, list)},
            "points_scores": points_scores}


def _jsonable(obj):
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
