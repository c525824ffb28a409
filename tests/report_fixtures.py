"""A tiny sweep for gspi-report tests: real gspi-eval outputs on two 32 px sphere scenes.

Jobs (each a gspi-run folder with result.json, predictions/, eval/, .hydra/config.yaml, run.log):
  gspi              every channel, roughness off by 0.1; a turntable and a (stand-in) GLB for sphere_0
  no_decomposition  albedo only (no roughness, no metallic)
  joint_ir          sphere_0 only (sphere_1 missing, named in scene_errors)
  table3_full, table3_a6_no_distill   Table 3 rows (copies of the gspi job)
  gs_ir             failed (status "failed")
  a killed job      .hydra/ without result.json
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from eval.config import ProtocolConfig, validate_protocol
from eval.evaluate import evaluate
from eval.records.eval_folder import write_result
from tests.fixtures import make_dataset, make_prediction

METHODS = ("gspi", "no_decomposition", "joint_ir")


def _record(job: Path, method: str, status: str = "complete", error=None, scenes=(), **extra):
    job.mkdir(parents=True, exist_ok=True)
    (job / ".hydra").mkdir(exist_ok=True)
    (job / ".hydra" / "config.yaml").write_text(f"method: {method}\nseed: 0\n")
    (job / "run.log").write_text(f"[info] {method}: started\n")
    record = {"format": "gspi-run", "format_version": 1, "status": status, "error": error,
              "method": method, "ablation": "full", "table": "table1", "seed": 0,  # overridable
              "config_hash": "abc", "data": "data", "scenes": list(scenes),
              "material_eval": "eval" if status == "complete" else None, "points_eval": None}
    record.update(extra)
    (job / "result.json").write_text(json.dumps(record))


def _turntable(path: Path, frames: int = 3, size: int = 16) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(np.full((size, size, 3), 60 * k, np.uint8)) for k in range(frames)]
    images[0].save(path, format="WEBP", save_all=True, append_images=images[1:], loop=0, duration=100)


def _glb(folder: Path) -> None:
    """A stand-in for gspi-export's output: a real GLB (a metallic-roughness box, which the
    report's viewer loads) and a preview image."""
    import trimesh
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box(extents=[1.0, 0.8, 0.6])
    box.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
        baseColorFactor=[200, 120, 60, 255], metallicFactor=0.2, roughnessFactor=0.4))
    (folder / "pbr_gs.glb").write_bytes(trimesh.Scene(box).export(file_type="glb"))
    Image.fromarray(np.full((16, 64, 3), 200, np.uint8)).save(folder / "pbr_gs_preview.png")


def make_sweep(root: Path, lpips_net) -> Path:
    """root/data (2 scenes) and root/runs/<job>/ as described above; returns root/runs."""
    data = make_dataset(root / "data", num_scenes=2, size=32)
    scenes = ["sphere_0", "sphere_1"]
    protocol = OmegaConf.structured(ProtocolConfig)
    validate_protocol(protocol)
    runs = root / "runs"
    specs = {"gspi": {}, "no_decomposition": {"channels": ("albedo",), "albedo_scale": 0.8},
             "joint_ir": {"albedo_scale": 1.3}}
    for method, kw in specs.items():
        job = runs / f"method={method}"
        pred = make_prediction(data, job / "predictions", method=method, **kw)
        extra = {}
        if method == "joint_ir":
            shutil.rmtree(pred / "sphere_1")
            extra["scene_errors"] = {"sphere_1": "RuntimeError: out of memory"}
        result = evaluate(data, pred, protocol, net=lpips_net, method=method)
        write_result(job / "eval", result, OmegaConf.to_container(protocol))
        _record(job, method, scenes=scenes, **extra)
    _turntable(runs / "method=gspi" / "relight" / "sphere_0" / "turntable.webp")
    _glb(runs / "method=gspi" / "export" / "sphere_0")
    for ablation in ("full", "a6_no_distill"):  # Table 3 rows: the gspi job's files, relabelled
        job = runs / f"table3_{ablation}"
        shutil.copytree(runs / "method=gspi", job, ignore=shutil.ignore_patterns("relight", "export"))
        _record(job, "gspi", scenes=scenes, table="table3", ablation=ablation)
    _record(runs / "method=gs_ir", "gs_ir", status="failed", error="ValueError: boom")
    (runs / "method=irgs" / ".hydra").mkdir(parents=True)  # killed before result.json
    return runs


_SHARED: dict = {}


def shared_report(tmp_path_factory, lpips_net):
    """(sweep folder, Site) built once per test session and shared by the report tests."""
    if "site" not in _SHARED:
        from eval.report_site.build import build_report

        root = tmp_path_factory.mktemp("report_sweep")
        sweep = make_sweep(root, lpips_net)
        _SHARED["sweep"] = sweep
        _SHARED["site"] = build_report([sweep], root / "report", bootstrap={"n": 200})
    return _SHARED["sweep"], _SHARED["site"]
