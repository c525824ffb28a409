"""Methods a run can score, behind one call: ``method.predict(scene, out_scene_dir) -> stats``.

``_target_`` in conf/method/<name>.yaml names the implementation (:func:`build_method`):

* :class:`GspiMethod`: GS-PI itself (gspi/pipeline.py): needs the scene's 2DGS asset and Stage II.
* :class:`LightFitMethod`: GS-PI's Stages I and III around the training-free light read-out.
* :class:`InhouseMethod`: baselines that run here (baselines/no_decomposition.py,
  baselines/joint_ir.py): need the asset; their code is ``baselines.<name>.predict_scene``, and
  an optional ``baselines.<name>.prepare(cfg, data_dir)`` does their per-run work.
* :class:`ExternalMethod`: another system's outputs, converted by its adapter (baselines/<name>.py)
  from ``method.outputs/<scene name>/``; no asset, no computation here.

``prepare`` does the per-run work once (loading or training Stage II, fitting constants).
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Optional

from hydra.utils import get_class

from eval.common.layout import Scene
from gspi.gaussians.model import Gaussians2D
from gspi.stage_clock import StageClock

if TYPE_CHECKING:
    from gspi.run.config_check import StageConfigs


class MethodUnavailable(RuntimeError):
    """The method cannot run here (e.g. an external system whose outputs are not configured)."""


class Method:
    """A configured method; ``needs_asset`` tells the runner whether to build the 2DGS asset."""

    needs_asset = True
    # the system reports its own runtime (meta.json of the import), not the time measured here
    reports_own_runtime = False
    # stages whose time is the method's "material estimation" runtime (Table 1)
    material_stages = ("stage1", "stage2", "stage3", "render", "material", "import")

    def __init__(self, cfg: Mapping[str, Any], run_cfg: Mapping[str, Any], cache_root: Path,
                 stages: "StageConfigs | None" = None):
        self.cfg, self.run_cfg, self.cache_root = {k: v for k, v in cfg.items() if k != "_target_"}, run_cfg, cache_root
        self.name = str(cfg["name"])
        self._stages = stages  # the run's checked stage configs (gspi.run.config_check), parsed at the door
        self.shared: dict[str, Any] = {}

    @property
    def stages(self) -> "StageConfigs":
        """The run's checked stage configs: those the door parsed, else parsed here once."""
        if self._stages is None:
            from gspi.run.config_check import parse_stage_configs

            self._stages = parse_stage_configs(self.run_cfg)
        return self._stages

    def prepare(self) -> dict:
        """Per-run set-up; returns what the run record should keep about it."""
        return {}

    def predict(self, scene: Scene, out_scene_dir: Path, *, asset: Optional[Gaussians2D], clock: StageClock,
                work_dir: Path, split: str, progress: bool = False) -> dict:
        """Writes ``out_scene_dir/<split>/<view>/{albedo,roughness,metallic}.png``; returns stats."""
        raise NotImplementedError


class GspiMethod(Method):
    """GS-PI: Stages I-III on the scene's asset (gspi/pipeline.py), Stage II shared by the run."""

    def prepare(self) -> dict:
        from gspi.run.stage2_model import load_stage2_context

        ctx = load_stage2_context(self.run_cfg, self.cache_root, self.stages.stage2)
        self.shared["stage2"] = ctx
        self.shared["stage1"], self.shared["stage3"] = self.stages.stage1, self.stages.stage3
        return {"stage2": {k: v for k, v in ctx.info.items() if k != "train_stats"}}

    def predict(self, scene, out_scene_dir, *, asset, clock, work_dir, split, progress=False) -> dict:
        from gspi.pipeline import run_gspi_scene

        return run_gspi_scene(scene, asset, out_scene_dir, self.run_cfg, stage1=self.shared["stage1"],
                              stage2=self.shared["stage2"], stage3=self.shared["stage3"],
                              clock=clock, work_dir=work_dir, split=split, progress=progress)


class LightFitMethod(GspiMethod):
    """GS-PI's Stages I and III around the training-free read-out in Stage II's place: the capture
    light estimated among ``method.candidates``, each point's material read against it
    (gspi/stage2/light_fit.py; conf/method/light_fit.yaml)."""

    def prepare(self) -> dict:
        from gspi.pipeline import LightFitContext
        from gspi.stage2.light_condition import candidate_lights
        from gspi.stage2.light_fit import LightFitConfig

        cfg = LightFitConfig.from_mapping(self.cfg)
        self.shared["stage2"] = LightFitContext(cfg=cfg, candidates=candidate_lights(cfg.candidates, cfg.env_height))
        self.shared["stage1"], self.shared["stage3"] = self.stages.stage1, self.stages.stage3
        return {"light_fit": {"candidates": sorted(self.shared["stage2"].candidates)}}


class InhouseMethod(Method):
    """A baseline run here: ``baselines.<name>.predict_scene`` (and its optional ``prepare``),
    given the run's resolved ``device`` (every in-house baseline takes ``device=``)."""

    def __init__(self, cfg, run_cfg, cache_root, stages=None):
        super().__init__(cfg, run_cfg, cache_root, stages)
        self.module = importlib.import_module(f"baselines.{self.name}")

    def prepare(self) -> dict:
        prepare = getattr(self.module, "prepare", None)
        if prepare is None:
            return {}
        self.shared, record = prepare(self.cfg, Path(self.run_cfg["data_dir"]))
        return record

    def predict(self, scene, out_scene_dir, *, asset, clock, work_dir, split, progress=False) -> dict:
        from gspi.device import resolve_device

        device = resolve_device(self.run_cfg.get("device", "cpu"))  # checked at start-up (check_run_config)
        with clock.stage("material"):
            return dict(self.module.predict_scene(scene, asset, out_scene_dir, self.cfg, split=split,
                                                  progress=progress, device=device, **self.shared) or {})


class ExternalMethod(Method):
    """Another system's placed outputs, imported by its adapter (baselines.adapter.import_placed_outputs)."""

    needs_asset = False
    reports_own_runtime = True

    def prepare(self) -> dict:
        if not self.cfg.get("outputs"):
            raise MethodUnavailable(f"method {self.name!r}: no outputs configured; place the system's outputs "
                                    f"under a folder and pass method.outputs=<folder> (docs/BASELINES.md)")
        from baselines.runtime import command_stages, given_runtime

        command_stages(self.cfg, len(self.cfg.get("commands") or []))  # checked before any import
        if self.cfg.get("runtime_s") is not None:
            given_runtime(self.cfg["runtime_s"])
        return {}

    def predict(self, scene, out_scene_dir, *, asset, clock, work_dir, split, progress=False) -> dict:
        from baselines.adapter import import_placed_outputs

        with clock.stage("import"):
            import_placed_outputs(self.cfg, scene.root, out_scene_dir.parent, split=split)
        return {"imported_from": str(Path(self.cfg["outputs"]) / scene.name)}


def build_method(cfg: Mapping[str, Any], run_cfg: Mapping[str, Any], cache_root: Path,
                 stages: "StageConfigs | None" = None) -> Method:
    """The :class:`Method` that ``cfg["_target_"]`` names, for the run ``run_cfg`` whose checked
    stage configs are ``stages`` (gspi.run.config_check; parsed on first use when not given)."""
    target = cfg.get("_target_")
    if not target:
        raise ValueError(f"method {cfg.get('name')!r}: no _target_ (conf/method/<name>.yaml names the Method class)")
    cls = get_class(str(target))
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise ValueError(f"method {cfg.get('name')!r}: _target_ {target} is not a gspi.run.methods.Method")
    return cls(cfg, run_cfg, cache_root, stages)
