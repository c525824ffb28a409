"""Table 2's measure of a saved Stage II model (the measure itself is ``gspi.stage2.points_measure``;
its console script, the measure named by a conf/points_measure option: ``gspi-points-eval``,
gspi/cli/points_eval.py). This module's argparse CLI takes the same knobs as flags.

``evaluate_checkpoint`` scores a model on a split's GT point clouds and writes ``scores.json``
(format ``gspi-points-eval``: the model's ablation, training seed, checkpoint, the dataset and
the sampling, so ``gspi-table`` builds Table 2 from such folders) and ``table.md``.
``--max-points N --num-steps 10 --split val`` is the validation's measure while training
(``gspi.stage2.validate``), so a saved ``best.pt`` scores here as it did when it was kept.

    python -m gspi.stage2.evaluate_points CHECKPOINT DATASET_DIR OUT_DIR [--num-steps 50]
        [--split test] [--max-points N] [--baseline-train DATA] [--num-samples K]
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any, Callable, Mapping

import torch

from eval.common.layout import LayoutError
from eval.points_protocol import MeasureError, measure_record
from eval.records.points_scores import write_points_scores
from gspi.stage2.data import ScenePoints
from gspi.stage2.points_measure import (CHANNELS, PSNR_CAP_DB, PointSampling, baseline_prediction,
                                        evaluate_scenes, subset_prediction, training_constants)
from gspi.stage2.splits import load_split

log = logging.getLogger(__name__)


def markdown_table(result: Mapping[str, Any], *, caption: str) -> str:
    """Rows = methods; per channel (+ avg) PSNR (dB), SSIM (%), LPIPS (%)."""
    names = {"stage2": "Stage II (ours)", "no_decomposition": "No decomposition (RGB as albedo)"}
    groups = list(CHANNELS) + ["avg"]
    head = "| method | " + " | ".join(f"{g} PSNR↑ | {g} SSIM(%)↑ | {g} LPIPS(%)↓" for g in groups) + " |"
    lines = [caption, "", head, "|---" * (1 + 3 * len(groups)) + "|"]
    for method, label in names.items():
        s = result["mean"][method]
        cells = [f"{s[g]['psnr']:.2f} | {100 * s[g]['ssim']:.2f} | {100 * s[g]['lpips']:.2f}" for g in groups]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def score_split(predict: Callable[[ScenePoints, int], Any], cfg: Mapping[str, Any], data_dir: str | Path,
                split: str, out_dir: str | Path, *, baseline_train: str | Path | None = None,
                record: Mapping[str, Any], told_light: str = "estimated") -> dict[str, Any]:
    """Table 2's measure of ``predict(scene, index) -> [P, 5]`` on ``split`` of ``data_dir``, with
    the no-decomposition baseline from ``baseline_train``'s train split (default ``data_dir``),
    written as ``<out_dir>/scores.json`` (format "gspi-points-eval": the dataset, split, scenes,
    baseline constants and measure, plus ``record``: what was scored). Returns the scores.
    Stage II models (``evaluate_checkpoint``) and any other point predictor (a study's direct
    regressors) are scored here. ``told_light``: the light a light-aware model's condition is told
    (``points_measure.told_light``: the estimate, or deliberately wrong)."""
    from gspi.stage2.encoders import build_encoder

    stage2 = cfg["stage2"]
    encoder = build_encoder(stage2.prior)
    scenes = load_split({**cfg, "data_dir": str(data_dir)}, split, encoder, light_source="estimated",
                        told_light=told_light)
    if baseline_train is not None and Path(baseline_train).suffix == ".json":
        rough, metal = recorded_constants(Path(baseline_train))
    else:
        try:
            train_scenes = load_split({**cfg, "data_dir": str(baseline_train or data_dir)}, "train", encoder,
                                      conditions=False)
        except ValueError as exc:  # e.g. a test-only dataset
            raise LayoutError(f"{exc}: the no-decomposition baseline's roughness/metallic are training means; "
                              "pass a dataset with a train split (--baseline-train, e.g. the model's training "
                              "data, or a scores.json that recorded them)") from exc
        rough, metal = training_constants(train_scenes)
    result = evaluate_scenes(scenes, lambda s: predict(s, scenes.index(s)), lambda s: baseline_prediction(s, rough, metal))
    result.update(checksums=scene_inputs_checksums(Path(data_dir), [s.name for s in scenes]),
                  train_seed=cfg.get("seed"), data=str(Path(data_dir).resolve()),
                  split=split, scenes=[s.name for s in scenes], baseline_constants={"roughness": rough, "metallic": metal},
                  baseline_train=str(Path(baseline_train or data_dir).resolve()), psnr_cap_db=PSNR_CAP_DB,
                  lpips="AlexNet LPIPS v0.1 (eval.lpips.net), masked_mean", encoder=stage2.prior.encoder,
                  **({"lights": {s.name: s.light_info for s in scenes}} if any(s.light_info for s in scenes) else {}),
                  **dict(record))
    write_points_scores(out_dir, result)  # eval.records.points_scores: the format's one writer
    return result


SCENE_INPUTS = ("scene.json", "gt_points.npz", "train")  # the truth and the lattice views the conditions come from


def scene_inputs_checksums(data_dir: Path, names: list[str]) -> dict[str, Any]:
    """SHA-256 of what each scene's measure read (``SCENE_INPUTS``: its GT points and the lattice
    views its conditions are taken from, e.g. a Stage 0 asset's renders), and over all scenes: two
    scores are one evaluation only if these agree (``eval.tables.sources``), which names the cause
    when a dataset was rebuilt with other bits (issue 53, session 27)."""
    from eval.checksums import ALGORITHM, files_sha256, over_scenes, tree_files

    per_scene = {n: files_sha256(data_dir / n, tree_files(data_dir / n, SCENE_INPUTS)) for n in names}
    return {"algorithm": f"{ALGORITHM}, over {', '.join(SCENE_INPUTS)}", "inputs": over_scenes(per_scene),
            "per_scene": per_scene}


def recorded_constants(scores: Path) -> tuple[float, float]:
    """The baseline's (roughness, metallic) recorded in an earlier ``scores.json`` (the same
    training means, without the training data at hand)."""
    from eval.records.points_scores import read_points_scores

    c = read_points_scores(scores).get("baseline_constants") or {}
    if "roughness" not in c or "metallic" not in c:
        raise LayoutError(f"{scores}: records no baseline_constants (roughness, metallic)")
    return float(c["roughness"]), float(c["metallic"])


def evaluate_checkpoint(model, cfg: Mapping[str, Any], data_dir: str | Path, out_dir: str | Path, *,
                        split: str = "test", num_steps: int = 50, seed: int = 0,
                        write_chunk: int | None = 32768, source: Mapping[str, Any] | None = None,
                        max_points: int | None = None, baseline_train: str | Path | None = None,
                        num_samples: int = 1, guidance_scale: float = 1.0, patch_points: int | None = None,
                        patch_coverage: float = 2.0, told_light: str = "estimated",
                        measure_name: str | None = None) -> dict[str, Any]:
    """Runs the evaluation of an (EMA) model with its training config on ``split`` of ``data_dir``.

    ``scores.json`` (format "gspi-points-eval") also records the model's ablation and training
    seed, the dataset and ``source`` (e.g. the checkpoint's path and step), so that
    ``gspi-table`` can build Table 2 from such folders (``eval/records/points_scores.py``).
    ``max_points``: predict a seeded subset of that many points per scene and fill the rest by
    1-NN (the validation measure, ``gspi.stage2.validate``); None = every point.
    ``baseline_train``: the dataset whose train split gives the baseline's constants (default
    ``data_dir``; e.g. the model's training pool when ``data_dir`` holds only test scenes).
    ``num_samples``: DDIM samples averaged per point (gspi-run's ``stage2.inference.num_samples``).
    ``guidance_scale``: classifier-free guidance (gspi-run's ``stage2.inference.guidance_scale``).
    ``patch_points`` / ``patch_coverage``: k-NN patch inference (``stage2.inference.patch_points``).
    ``told_light``: what a light-aware model (``stage2.data.light_readout``) is told: the estimated
    light, or deliberately wrong, ``turned90`` / ``other`` (issue 66's guard rail).
    ``measure_name``: the conf/points_measure option these knobs came from (gspi-points-eval), recorded
    with the knobs' hash as ``measure_protocol`` (``eval.points_protocol``); None: set by flags.

    Writes ``<out_dir>/scores.json`` and ``<out_dir>/table.md``; returns the scores.
    """
    data_cfg = cfg["stage2"].data
    if told_light != "estimated" and not data_cfg.light_readout:
        raise MeasureError(f"points_measure.told_light={told_light}: this model reads no light "
                           "(stage2.data.light_readout is false); a wrong light changes nothing it is given")
    sampling = PointSampling(num_steps=num_steps, max_points=max_points, seed=seed, num_samples=num_samples,
                             guidance_scale=guidance_scale, patch_points=patch_points, patch_coverage=patch_coverage)

    def predict(scene: ScenePoints, index: int):
        return subset_prediction(model, scene, index, data_cfg, sampling, write_chunk=write_chunk)

    measure = {"split": split, "told_light": told_light,
               **{k: getattr(sampling, k) for k in ("num_steps", "max_points", "seed", "num_samples",
                                                    "guidance_scale", "patch_points", "patch_coverage")}}
    result = score_split(predict, cfg, data_dir, split, out_dir, baseline_train=baseline_train, told_light=told_light,
                         record={"ablation": str(cfg.get("ablation_name", "full")), **dict(source or {}),
                                 "measure_protocol": measure_record(measure_name, measure),
                                 "num_steps": num_steps, "max_points": max_points, "seed": seed,
                                 **({"num_samples": num_samples} if num_samples != 1 else {}),
                                 **({"guidance_scale": guidance_scale} if guidance_scale != 1.0 else {}),
                                 **({"told_light": told_light} if told_light != "estimated" else {}),
                                 **({"patch_points": patch_points, "patch_coverage": patch_coverage}
                                    if patch_points else {})})
    out_dir = Path(out_dir)
    rough, metal = result["baseline_constants"]["roughness"], result["baseline_constants"]["metallic"]
    scenes = result["scenes"]
    sampling_note = f", {num_samples} samples averaged" if num_samples != 1 else ""
    sampling_note += f", guidance {guidance_scale:g}" if guidance_scale != 1.0 else ""
    sampling_note += f", {patch_points}-point patches x{patch_coverage:g}" if patch_points else ""
    sampling_note += f", told a wrong light ({told_light})" if told_light != "estimated" else ""
    caption = (f"Stage II on the GT point clouds of {len(scenes)} {split} scenes of {Path(data_dir).name} "
               f"({num_steps} DDIM steps, seed {seed}{sampling_note}); per-view masked metrics averaged over the 32 lattice "
               f"views and the scenes; PSNR capped at {PSNR_CAP_DB:.0f} dB per view; LPIPS = AlexNet v0.1. "
               f"Baseline constants (training means): roughness {rough:.3f}, metallic {metal:.3f}.")
    (out_dir / "table.md").write_text(markdown_table(result, caption=caption))
    return result


def checkpoint_source(path: str | Path) -> dict[str, Any]:
    """Where a model came from: the checkpoint's path, training step and training seconds."""
    from gspi.stage2.checkpoint import read_checkpoint

    saved = read_checkpoint(Path(path))
    return {"checkpoint": str(Path(path).resolve()), "checkpoint_step": int(saved.get("step", -1)),
            "checkpoint_elapsed_s": saved.get("elapsed_s")}


def main(argv: list[str] | None = None) -> None:
    from gspi.stage2.checkpoint import load_stage2_checkpoint

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("data")
    parser.add_argument("out")
    parser.add_argument("--split", default="test")
    parser.add_argument("--num-steps", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num-samples", type=int, default=1,
                        help="DDIM samples averaged per point (gspi-run's stage2.inference.num_samples)")
    parser.add_argument("--guidance-scale", type=float, default=1.0,
                        help="classifier-free guidance (gspi-run's stage2.inference.guidance_scale; 1 = off)")
    parser.add_argument("--patch-points", type=int, default=None,
                        help="k-NN patches of this many points, blended (stage2.inference.patch_points); default the whole cloud")
    parser.add_argument("--patch-coverage", type=float, default=2.0, help="patches per point on average")
    parser.add_argument("--max-points", type=int, default=None,
                        help="per scene: a seeded subset + 1-NN fill (the validation measure); default every point")
    parser.add_argument("--baseline-train", default=None,
                        help="dataset whose train split gives the baseline's constants (default: DATA), "
                             "or a scores.json whose recorded constants to reuse")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(args.threads)
    model, cfg = load_stage2_checkpoint(args.checkpoint)
    evaluate_checkpoint(model, cfg, args.data, args.out, split=args.split, num_steps=args.num_steps, seed=args.seed,
                        source=checkpoint_source(args.checkpoint), max_points=args.max_points,
                        baseline_train=args.baseline_train, num_samples=args.num_samples,
                        guidance_scale=args.guidance_scale, patch_points=args.patch_points,
                        patch_coverage=args.patch_coverage)
    print((Path(args.out) / "table.md").read_text())


if __name__ == "__main__":
    from eval.common.errors import run_command

    run_command(main)  # a stated error or Ctrl-C: one line (exit 2 / 130)
