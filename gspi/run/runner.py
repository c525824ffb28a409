"""One `gspi-run` job: a method on a dataset's scenes, scored, recorded, tracked.

    <out>/
      predictions/<scene>/{meta.json, <views>/<view>/*.png} canonical layout (docs/FORMAT.md);
                                                            <views> = eval.split (test | train)
      work/<scene>/                                         intermediate files (pipeline.py)
      eval/        per_view.csv, summary.json, eval_meta.json   (as gspi-eval writes them)
      points_eval/points_summary.json                        Table 2's measure (GS-PI only)
      figures/<scene>.png                                    GT vs prediction, PSNR under each
      result.json                                            written LAST (gspi/run/record.py)

Record protocol (docs/RELIABILITY.md): a job that is not skipped first removes the folder's
result.json, then every output of another config (eval/, points_eval/, figures/ and prediction
scenes whose meta.json carries another config hash), and writes the new result.json LAST; so a
job killed at any point leaves no record, gspi-table lists it as unfinished and a rerun of any
config redoes it.

Failure policy: an error in one scene is recorded (traceback in the log, message in
result.json) and the other scenes go on; the job then ends "failed" and its finished scenes
stay on disk. A rerun of the same config skips a complete job, and inside a failed one redoes
only the scenes without a finished prediction (their meta.json carries the config hash).
"""
from __future__ import annotations

import logging
import shutil
import time
import traceback
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch

from eval.common.layout import LayoutError, Scene, read_meta, read_scene, read_splits, scene_dir_in, write_meta
from eval.common.atomic import write_json_atomic
from eval.common.errors import MissingInputError, StatedError, one_line
from eval.records import run_points
from eval.records.eval_folder import RESULT_FILES
from gspi.device import resolve_device
from gspi.recon.reconstruct import reconstruction_seconds
from gspi.run.assets import check_prediction_covers_scene, scene_asset
from gspi.run.methods import Method, build_method
from gspi.run.record import config_hash, invalidate_result, is_complete, read_result, write_result
from gspi.stage_clock import StageClock
from gspi.run.tracking import flatten, make_tracker

log = logging.getLogger(__name__)


def select_scenes(data_dir: Path, split: str, scenes: Optional[list[str]]) -> list[str]:
    """The run's scene names: ``scenes`` if given (checked), else the dataset split's."""
    if scenes:
        missing = [s for s in scenes if not (data_dir / s / "scene.json").is_file()]
        if missing:
            raise MissingInputError(f"{data_dir}: scenes not found: {missing}")
        return list(scenes)
    if (data_dir / "scene.json").is_file():  # a single scene folder
        return [data_dir.name]
    names = read_splits(data_dir).get(split, [])
    if not names:
        raise LayoutError(f"{data_dir / 'splits.json'}: split {split!r} has no scenes")
    return names


def scene_done(pred_scene: Path, cfg_hash: str, scene: Scene, split: str) -> bool:
    """A finished prediction of this config: meta.json with the hash and every view folder."""
    meta = read_meta(pred_scene) if (pred_scene / "meta.json").is_file() else {}
    if meta.get("config_hash") != cfg_hash:
        return False
    return all((pred_scene / split / v.id).is_dir() for v in scene.split_views(split))


def view_split(cfg: Mapping[str, Any]) -> str:
    """The views a job predicts and scores: the protocol's ``eval.split`` (``lattice`` = the
    ``train`` folder). The job's own ``split`` picks the dataset's scenes, not their views."""
    from eval.protocol_id import scored_split

    return scored_split(dict(cfg["eval"]))


def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)


def run_scene(name: str, *, data_dir: Path, method: Method, cfg: Mapping[str, Any], out: Path,
              cfg_hash: str, cache_root: Path, num_scenes: int, progress: bool = False) -> dict:
    """Predicts one scene into ``out/predictions/<name>`` and writes its meta.json."""
    scene = read_scene(scene_dir_in(data_dir, name) or data_dir / name)
    split = view_split(cfg)
    pred_scene, work = out / "predictions" / name, out / "work" / name
    if scene_done(pred_scene, cfg_hash, scene, split):
        log.info("%s: finished prediction found, reused", name)
        return read_meta(pred_scene)
    seed_everything(int(cfg["seed"]))
    clock = StageClock(name, tag=str(cfg.get("ablation_name", "")))
    asset, asset_info = None, {}
    if method.needs_asset:
        with clock.stage("recon"):
            asset, asset_info = scene_asset(scene, assets=cfg.get("assets"), asset_check=cfg.get("asset_check"),
                                            num_scenes=num_scenes,
                                            recon_cfg=cfg["recon"], cache_root=cache_root,
                                            device=str(resolve_device(cfg.get("device", "cpu"))))
    stats = method.predict(scene, pred_scene, asset=asset, clock=clock, work_dir=work, split=split,
                           progress=progress)
    coverage = check_prediction_covers_scene(scene, pred_scene, split)  # black maps fail the scene
    if isinstance(stats, dict):
        stats["foreground_coverage"] = round(coverage, 4)
    material_s = clock.seconds(*method.material_stages)
    recon_s = reconstruction_seconds(asset_info) if asset_info.get("source") == "recon" else None
    end_to_end = None if (method.needs_asset and recon_s is None) else material_s + float(recon_s or 0.0)
    geometry_s = recon_s
    if method.reports_own_runtime:  # the system's own runtime (user value or timed run), not the import's
        runtime = read_meta(pred_scene).get("runtime_s", {})
        material_s, end_to_end = runtime.get("material"), runtime.get("end_to_end")
        geometry_s = runtime.get("geometry")
    points_scores = stats.pop("points_scores", None) if isinstance(stats, dict) else None
    if points_scores is not None:
        write_json_atomic(work / "points_scores.json", points_scores)
    write_meta(pred_scene, method=method.name, material_s=None if material_s is None else round(material_s, 3),
               end_to_end_s=None if end_to_end is None else round(end_to_end, 3),
               geometry_s=None if geometry_s is None else round(float(geometry_s), 3), config_hash=cfg_hash,
               stages=clock.stages, asset={k: v for k, v in asset_info.items() if k not in ("config", "history")},
               stats=stats)
    return read_meta(pred_scene)


def _run_scene_safely(name: str, scene_args: dict, progress: bool) -> tuple[str, Optional[dict], Optional[str]]:
    """(name, meta.json, None) or (name, None, "<error type>: <message>"), the traceback logged."""
    try:
        return name, run_scene(name, progress=progress, **scene_args), None
    except StatedError as exc:  # names its key or file: one line, no traceback
        log.error("%s: %s failed: %s", name, scene_args["method"].name, one_line(exc))
        return name, None, StatedMessage(f"{type(exc).__name__}: {one_line(exc)}")
    except Exception as exc:
        log.error("%s: %s failed:\n%s", name, scene_args["method"].name, traceback.format_exc())
        return name, None, f"{type(exc).__name__}: {exc}"


class StatedMessage(str):
    """A scene's error message from a stated error (picklable across scene workers)."""


class ScenesFailedError(StatedError, RuntimeError):
    """Every failed scene of a job failed with a stated error: the job's one-line error."""


LOG_FORMAT = "[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"  # Hydra's job_logging format


def _init_scene_worker(threads: int, log_files: list[str]) -> None:
    """A scene worker (a fresh spawned process): its torch threads, and its log lines on stderr
    and appended to the parent's log files (the Hydra job log), as a serial run would have them."""
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT)
    for path in log_files:
        handler = logging.FileHandler(path, mode="a")
        handler.setFormatter(logging.Formatter(LOG_FORMAT))
        logging.getLogger().addHandler(handler)
    torch.set_num_threads(threads)


def predict_scenes(names: list[str], scene_args: dict, *, workers: int = 1, progress: bool = True):
    """Yields ``(name, meta, error)`` per scene as it finishes (:func:`run_scene` on each).

    ``workers > 1`` runs that many scenes at once, each in a spawned process with ``threads``
    torch threads. Every scene seeds itself (``seed_everything``) and writes only its own
    folders, so the predictions are the same as a serial run's; the method's prepared state
    (e.g. the loaded Stage II model) is pickled to the workers, not prepared again. Scene
    progress bars are off in the workers (one bar over scenes instead).
    """
    workers = max(1, min(int(workers), len(names)))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(names), desc=scene_args["method"].name, unit="scene")
    try:
        if workers == 1:
            for name in names:
                yield _run_scene_safely(name, scene_args, progress)
                if bar is not None:
                    bar.update()
            return
        from concurrent.futures import as_completed

        # loky's executor (joblib's; spawned workers, no fork) rather than concurrent.futures': a
        # job of a `hydra/launcher=joblib` sweep runs inside a loky worker, whose multiprocessing
        # start method "loky" a plain spawned child cannot resolve ("cannot find context").
        from joblib.externals.loky import ProcessPoolExecutor

        threads = int(scene_args["cfg"].get("threads", 1))
        log_files = [h.baseFilename for h in logging.getLogger().handlers if isinstance(h, logging.FileHandler)]
        with ProcessPoolExecutor(workers, initializer=_init_scene_worker, initargs=(threads, log_files)) as pool:
            futures = {pool.submit(_run_scene_safely, name, scene_args, False): name for name in names}
            for future in as_completed(futures):
                try:
                    result = future.result()
                except Exception as exc:  # the worker itself died (e.g. killed for memory)
                    name = futures[future]
                    log.error("%s: scene worker failed: %s", name, exc)
                    result = (name, None, f"{type(exc).__name__}: {exc}")
                if bar is not None:
                    bar.update()
                yield result
    finally:
        if bar is not None:
            bar.close()


def points_summary(out: Path, names: list[str]) -> Optional[dict]:
    """Table 2's measure over the scenes that have one: {"mean": ..., "per_scene": ...}."""
    import json

    per_scene = {}
    for name in names:
        path = out / "work" / name / "points_scores.json"
        if path.is_file():
            per_scene[name] = json.loads(path.read_text())
    if not per_scene:
        return None
    channels = [c for c in ("albedo", "roughness", "metallic", "avg") if c in next(iter(per_scene.values()))]
    mean = {c: {m: float(np.mean([s[c][m] for s in per_scene.values()])) for m in ("psnr", "ssim", "lpips")}
            for c in channels}
    return {"mean": mean, "per_scene": per_scene}


# Rebuilt by every job that is not skipped: the files removed first (by name, never a whole
# folder, so `out=.` cannot delete anything but these).
DERIVED_FILES = {"eval": RESULT_FILES,
                 run_points.FOLDER: (run_points.NAME, run_points.LEGACY_NAME), "figures": ("*.png",)}


def clear_stale_outputs(out: Path, cfg_hash: str) -> list[str]:
    """Removes what a job of another config (or a killed one) left that this job would not
    overwrite file by file: the derived folders, and prediction scenes of another config hash
    (a method that predicts fewer channels must not inherit the old ones). Returns what it removed."""
    removed = []
    for folder, patterns in DERIVED_FILES.items():
        for path in sorted(p for pattern in patterns for p in (out / folder).glob(pattern) if p.is_file()):
            path.unlink()
            removed.append(str(path.relative_to(out)))
    pred_root = out / "predictions"
    for scene_dir in sorted(pred_root.iterdir()) if pred_root.is_dir() else []:
        try:
            meta = read_meta(scene_dir) if scene_dir.is_dir() else {}
        except ValueError:  # an unreadable meta.json: not a finished prediction of this config
            meta = {}
        if scene_dir.is_dir() and meta.get("config_hash") != cfg_hash:
            shutil.rmtree(scene_dir)
            removed.append(f"predictions/{scene_dir.name}")
    return removed


def evaluate_predictions(cfg: Mapping[str, Any], data_dir: Path, out: Path, method_name: str,
                         cfg_hash: Optional[str] = None):
    """gspi-eval on ``out/predictions`` into ``out/eval``; returns the EvalResult (its
    eval_meta.json carries the job's config hash, so the scores name the config they are of)."""
    from omegaconf import OmegaConf

    from eval.config import validate_protocol
    from eval.evaluate import evaluate
    from eval.records.eval_folder import write_result as write_eval

    protocol = OmegaConf.create(cfg["eval"])
    validate_protocol(protocol)
    result = evaluate(data_dir, out / "predictions", protocol, method=method_name,
                      device=resolve_device(cfg.get("device", "cpu")))  # the run's device
    if cfg_hash is not None:
        result.info["config_hash"] = cfg_hash
    write_eval(out / "eval", result, dict(cfg["eval"]))
    return result


def scored_inputs(eval_info: Mapping[str, Any]) -> dict:
    """What the record states about its scores (issue 53): the protocol hash and the SHA-256
    checksums of the predictions and of the ground truth they were scored against
    (eval/checksums.py; per scene in eval/eval_meta.json)."""
    sums = eval_info["checksums"]
    return {"protocol_hash": eval_info["protocol"]["hash"],
            "checksums": {k: sums[k] for k in ("algorithm", "predictions", "ground_truth")}}


def run_job(cfg: Mapping[str, Any], *, reraise: bool = True) -> dict:
    """Runs (or skips, when complete) one job; returns its result.json content. The job's
    ``seed`` offsets every stage's own seed first (``gspi.run.seeds``)."""
    from gspi.run.seeds import with_run_seed

    cfg = with_run_seed(cfg)
    out, data_dir = Path(cfg["out"]), Path(cfg["data_dir"])
    cfg_hash = config_hash(cfg)
    if is_complete(out, cfg_hash):
        log.info("%s: complete result of this config found, skipped", out)
        return read_result(out)
    from gspi.run.config_check import check_run_config

    stages = check_run_config(cfg)  # bad types or ranges fail here, before anything is written
    names = select_scenes(data_dir, cfg["split"], cfg.get("scenes"))  # a bad data path too (no wandb yet)
    out.mkdir(parents=True, exist_ok=True)
    old = invalidate_result(out)  # from here on, no record describes this folder until ours
    removed = clear_stale_outputs(out, cfg_hash)
    if old is not None or removed:
        log.info("%s: previous record (%s) removed; stale outputs removed: %s", out,
                 None if old is None else f"{old.get('status')}, config {old.get('config_hash')}",
                 ", ".join(removed) or "none")
    torch.set_num_threads(int(cfg.get("threads", 1)))
    cache_root = Path(cfg.get("cache_dir") or data_dir / ".cache")
    method_cfg = cfg["method"]
    record = dict(cfg_hash=cfg_hash, method=str(method_cfg["name"]), ablation=str(cfg.get("ablation_name", "full")),
                  table=cfg.get("table"), seed=int(cfg["seed"]), data=str(data_dir))
    tracker = make_tracker(cfg.get("logger"), cfg, out)
    t0 = time.perf_counter()
    try:
        method = build_method(method_cfg, cfg, cache_root, stages)
        prepared = method.prepare()
        errors = {}
        scene_args = dict(data_dir=data_dir, method=method, cfg=cfg, out=out, cfg_hash=cfg_hash,
                          cache_root=cache_root, num_scenes=len(names))
        for name, meta, error in predict_scenes(names, scene_args, workers=int(cfg.get("scene_workers", 1)),
                                                progress=bool(cfg.get("progress", True))):
            if error is None:
                tracker.log(flatten(f"{name}/stages", meta.get("stages", {})))
            else:  # one scene failing must not lose the others
                errors[name] = error
        done = [n for n in names if n not in errors]
        material_eval = points_eval = None
        scored: dict = {}
        if done:
            result = evaluate_predictions(cfg, data_dir, out, method.name, cfg_hash)
            material_eval = "eval"
            scored = scored_inputs(result.info)
            tracker.log(flatten("eval", result.summary))
            tracker.summary(flatten("eval", result.summary))
            import pandas as pd
            tracker.log_table("eval/per_view", pd.DataFrame(result.rows))
            pts = points_summary(out, done)
            if pts is not None:
                run_points.write_run_points(out, pts)
                points_eval = run_points.FOLDER
                tracker.summary(flatten("points_eval", pts["mean"]))
            if cfg.get("figures", True):
                write_figures(cfg, data_dir, out, done, tracker)
        status = "failed" if errors else "complete"
        error = None if not errors else "; ".join(f"{k}: {v}" for k, v in errors.items())
        write_result(out, status=status, error=error, scenes=names, material_eval=material_eval,
                     points_eval=points_eval, extra={"prepare": prepared, "scene_errors": errors,
                                                     "seconds": round(time.perf_counter() - t0, 2),
                                                     **scored}, **record)
        tracker.finish(exit_code=0 if not errors else 1)
        if errors and reraise:
            kind = ScenesFailedError if all(isinstance(e, StatedMessage) for e in errors.values()) else RuntimeError
            raise kind(f"{out}: {len(errors)} of {len(names)} scenes failed: {error}")
    except Exception as exc:
        if read_result(out) is None or read_result(out).get("config_hash") != cfg_hash or \
                read_result(out).get("status") != "failed":
            write_result(out, status="failed", error=f"{type(exc).__name__}: {exc}", scenes=names,
                         extra={"traceback": traceback.format_exc()}, **record)
        tracker.finish(exit_code=1)
        if reraise:
            raise
        log.error("%s: job failed, recorded in result.json:\n%s", out, traceback.format_exc())
    return read_result(out)


def write_figures(cfg: Mapping[str, Any], data_dir: Path, out: Path, names: list[str], tracker) -> None:
    from omegaconf import OmegaConf

    from eval.report_site.run_figure import scene_figure

    protocol = OmegaConf.create(cfg["eval"])
    for name in names:
        scene_dir = scene_dir_in(data_dir, name) or data_dir / name
        try:
            path = scene_figure(read_scene(scene_dir), out / "predictions" / name, out / "figures" / f"{name}.png",
                                protocol, split=view_split(cfg))
            tracker.log_image(f"figures/{name}", path)
        except Exception:  # a figure must never fail a run
            log.warning("%s: figure failed:\n%s", name, traceback.format_exc())
