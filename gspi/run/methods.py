"""Methods a run can score, behind one call: ``method.predict(scene, out_scene_dir) -> stats``.

``method.kind`` in conf/method/<name>.yaml picks the implementation:

* ``pipeline``: GS-PI itself (gspi/pipeline.py): needs the scene's 2DGS asset and Stage II.
* ``inhouse``: baselines that run here (baselines/no_decomposition.py, baselines/joint_ir.py):
  need the asset; their code is ``baselines.<name>.predict_scene``.
* ``external``: another system's outputs, converted by its adapter (baselines/<name>.py)
  from ``method.outputs/<scene name>/``; no asset, no computation here.

``prepare`` does the per-run work once (loading or training Stage II, fitting constants).
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Callable, Mapping, Optional

from eval.layout import Scene
from gspi.gaussians.model import Gaussians2D
from gspi.stage_clock import StageClock

KINDS = ("pipeline", "inhouse", "external")


class MethodUnavailable(RuntimeError):
    """The method cannot run here (e.g. an external system whose outputs are not configured)."""


class Method:
    """A configured method; ``needs_asset`` tells the runner whether to build the 2DGS asset."""

    def __init__(self, cfg: Mapping[str, Any], run_cfg: Mapping[str, Any], cache_root: Path):
        self.cfg, self.run_cfg, self.cache_root = dict(cfg), run_cfg, cache_root
        self.name = str(cfg["name"])
        self.kind = str(cfg.get("kind", ""))
        if self.kind not in KINDS:
            raise ValueError(f"method {self.name!r}: kind must be one of {KINDS}, got {self.kind!r}")
        self.needs_asset = self.kind != "external"
        self.shared: dict[str, Any] = {}

    def prepare(self) -> dict:
        """Per-run set-up; returns what the run record should keep about it."""
        if self.kind == "pipeline":
            from gspi.run.stage2_model import load_stage2_context

            ctx = load_stage2_context(self.run_cfg, self.cache_root)
            self.shared["stage2"] = ctx
            return {"stage2": {k: v for k, v in ctx.info.items() if k != "train_stats"}}
        if self.kind == "inhouse" and self.name == "no_decomposition":
            from baselines.no_decomposition import fit_constants
            from eval.layout import read_splits

            data_dir = Path(self.run_cfg["data_dir"])
            has_train = (data_dir / "splits.json").is_file() and read_splits(data_dir).get("train")
            if has_train or not self.cfg.get("fallback_constants"):
                self.shared["constants"] = fit_constants(data_dir)
                return {"constants": self.shared["constants"], "constants_source": "fitted on the training split"}
            self.shared["constants"] = {k: float(v) for k, v in self.cfg["fallback_constants"].items()}
            return {"constants": self.shared["constants"],
                    "constants_source": "method.fallback_constants (the dataset has no training scenes)"}
        if self.kind == "external" and not self.cfg.get("outputs"):
            raise MethodUnavailable(f"method {self.name!r}: no outputs configured; place the system's outputs "
                                    f"under a folder and pass method.outputs=<folder> (docs/BASELINES.md)")
        return {}

    def predict(self, scene: Scene, out_scene_dir: Path, *, asset: Optional[Gaussians2D], clock: StageClock,
                work_dir: Path, split: str, progress: bool = False) -> dict:
        """Writes ``out_scene_dir/<split>/<view>/{albedo,roughness,metallic}.png``; returns stats."""
        if self.kind == "pipeline":
            from gspi.pipeline import run_gspi_scene

            return run_gspi_scene(scene, asset, out_scene_dir, self.run_cfg, stage2=self.shared["stage2"],
                                  clock=clock, work_dir=work_dir, split=split, progress=progress)
        if self.kind == "inhouse":
            predict_scene: Callable = importlib.import_module(f"baselines.{self.name}").predict_scene
            kwargs = {"constants": self.shared["constants"]} if "constants" in self.shared else {}
            with clock.stage("material"):
                return dict(predict_scene(scene, asset, out_scene_dir, self.cfg, progress=progress, **kwargs) or {})
        return self._import_external(scene, out_scene_dir, clock)

    def _import_external(self, scene: Scene, out_scene_dir: Path, clock: StageClock) -> dict:
        from baselines.adapter import get_adapter

        src = Path(self.cfg["outputs"]) / scene.name
        if not src.is_dir():
            raise FileNotFoundError(f"{src}: no outputs of {self.name} for scene {scene.name}")
        with clock.stage("import"):
            get_adapter(self.name).import_outputs(src, scene.root, out_scene_dir.parent, self.cfg)
        return {"imported_from": str(src)}

    @property
    def material_stages(self) -> tuple[str, ...]:
        """Stages whose time is the method's "material estimation" runtime (Table 1)."""
        return ("stage1", "stage2", "stage3", "render", "material", "import")
