"""Table 2's measure: Stage II on the generated point cloud, scored in the lattice views.

For each scene of a split: its GT point cloud (the lattice-view unprojection, perturbed as in
training with a seeded generator), Stage II predictions for all points at once
(``predict_point_pbr``, EMA weights), scattered back into the per-view maps of the 32 lattice
views through the stored source pixels, and scored against the GT maps (``albedo.png``,
``roughness.png``, ``metallic.png``) with ``eval.metrics`` (masked PSNR / SSIM / LPIPS; mask =
the pixels that received a point). The same is done for the no-decomposition baseline:
albedo = the observed colour ``sRGB(clamp(rgb_linear))`` (the Top-RGB), roughness and
metallic = the mean of the training points' values (the L2-optimal constants).

Per view and channel scores are averaged over the 32 views, then over scenes; "avg" is the
mean of the three channels (Table 2 reports averages over albedo, roughness, metallic). A
per-view PSNR is capped at ``PSNR_CAP_DB``: an exact match (e.g. metallic 0 predicted on a
plastic) is otherwise inf and would make every mean inf.

    python -m gspi.stage2.evaluate_points CHECKPOINT DATASET_DIR OUT_DIR [--num-steps 50]
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch

from eval.atomic import write_json_atomic
from gspi.stage2.data import PointDataConfig, ScenePoints
from gspi.stage2.normalize import pbr_from_model
from gspi.data.gt_maps import read_gt_view_maps
from gspi.point_cloud import scatter_pixel_values

log = logging.getLogger(__name__)
CHANNELS = {"albedo": slice(0, 3), "roughness": slice(3, 4), "metallic": slice(4, 5)}
PSNR_CAP_DB = 60.0
METRICS = ("psnr", "ssim", "lpips")


def scatter_to_views(values: np.ndarray, scene: ScenePoints) -> tuple[np.ndarray, np.ndarray]:
    """Per-point values [P, C] -> per-view maps [V, H, W, C] and mask [V, H, W] (pixels hit)."""
    cams = scene.cameras
    return scatter_pixel_values(scene.view, scene.pixel, values, height=cams.height, width=cams.width,
                                num_views=len(cams.K))


def score_maps(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray, lpips_net) -> dict[str, dict[str, float]]:
    """Scores [V, H, W, 5] predictions: {channel: {metric: mean over views}}."""
    from eval.metrics import masked_lpips, masked_psnr, masked_ssim

    out = {}
    for channel, sl in CHANNELS.items():
        rows = []
        for v in range(len(pred)):
            if not mask[v].any():
                continue
            p, g, m = (torch.from_numpy(pred[v, ..., sl]), torch.from_numpy(gt[v, ..., sl]),
                       torch.from_numpy(mask[v]))
            rows.append((min(masked_psnr(p, g, m), PSNR_CAP_DB), masked_ssim(p, g, m),
                         masked_lpips(p, g, m, net=lpips_net)))
        out[channel] = dict(zip(METRICS, np.mean(rows, axis=0).tolist()))
    return out


def training_constants(train_scenes: list[ScenePoints]) -> tuple[float, float]:
    """Mean roughness and metallic over all training points (the L2-optimal constants)."""
    f0 = np.concatenate([s.f0 for s in train_scenes])
    pbr = pbr_from_model(torch.from_numpy(f0)).numpy()
    return float(pbr[:, 3].mean()), float(pbr[:, 4].mean())


def baseline_prediction(scene: ScenePoints, roughness: float, metallic: float) -> np.ndarray:
    """[P, 5] no-decomposition prediction: albedo = Top-RGB (sRGB), constant roughness/metallic."""
    const = np.broadcast_to(np.array([roughness, metallic], dtype=np.float32), (scene.num_points, 2))
    return np.concatenate([scene.top_rgb, const], axis=1)


def evaluate_scenes(scenes: list[ScenePoints], predict: Callable[[ScenePoints], np.ndarray],
                    baseline: Callable[[ScenePoints], np.ndarray], *, lpips_net=None) -> dict[str, Any]:
    """{"stage2": {scene: scores}, "no_decomposition": {...}, "mean": {method: scores}}."""
    from eval.lpips_net import load_lpips

    net = lpips_net if lpips_net is not None else load_lpips()
    per_scene: dict[str, dict] = {"stage2": {}, "no_decomposition": {}}
    metal_iou: dict[str, dict] = {"stage2": {}, "no_decomposition": {}}
    timings = {}
    for scene in scenes:
        gt = read_gt_view_maps(scene.root)[0]
        t0 = time.perf_counter()
        pred = predict(scene)
        timings[scene.name] = round(time.perf_counter() - t0, 2)
        for method, values in (("stage2", pred), ("no_decomposition", baseline(scene))):
            maps, mask = scatter_to_views(values, scene)
            per_scene[method][scene.name] = score_maps(maps, gt, mask, net)
            metal_iou[method][scene.name] = point_metal_iou(values[:, 4], scene)
        log.info("%s: %d points, predicted in %.1f s; albedo PSNR %.2f (baseline %.2f)", scene.name,
                 scene.num_points, timings[scene.name], per_scene["stage2"][scene.name]["albedo"]["psnr"],
                 per_scene["no_decomposition"][scene.name]["albedo"]["psnr"])
    mean = {m: average_scores(list(s.values())) for m, s in per_scene.items()}
    return {"per_scene": per_scene, "mean": mean, "predict_time_s": timings, "metal_iou": metal_iou}


def point_metal_iou(metallic: np.ndarray, scene: ScenePoints, threshold: float = 0.5) -> float | None:
    """IoU of {metallic > threshold} between a prediction [P] and the GT points (one point per
    lattice pixel, so it is the pixel IoU over the 32 views); None when neither has metal."""
    gt = pbr_from_model(torch.from_numpy(scene.f0[:, 4])).numpy() > threshold
    pred = np.asarray(metallic) > threshold
    union = int(np.count_nonzero(gt | pred))
    return None if union == 0 else float(np.count_nonzero(gt & pred)) / union


def average_scores(scores: list[dict]) -> dict[str, dict[str, float]]:
    """Mean over scenes per channel and metric, plus "avg" = mean over the three channels."""
    out = {c: {m: float(np.mean([s[c][m] for s in scores])) for m in METRICS} for c in CHANNELS}
    out["avg"] = {m: float(np.mean([out[c][m] for c in CHANNELS])) for m in METRICS}
    return out


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


def evaluate_checkpoint(model, cfg: Mapping[str, Any], data_dir: str | Path, out_dir: str | Path, *,
                        split: str = "test", num_steps: int = 50, seed: int = 0,
                        write_chunk: int | None = 32768, source: Mapping[str, Any] | None = None,
                        max_points: int | None = None, baseline_train: str | Path | None = None
                        ) -> dict[str, Any]:
    """Runs the evaluation of an (EMA) model with its training config on ``split`` of ``data_dir``.

    ``scores.json`` (format "gspi-points-eval") also records the model's ablation and training
    seed, the dataset and ``source`` (e.g. the checkpoint's path and step), so that
    ``gspi-table`` can build Table 2 from such folders (``eval/points_folders.py``).
    ``max_points``: predict a seeded subset of that many points per scene and fill the rest by
    1-NN (the validation measure, ``gspi.stage2.validate``); None = every point.
    ``baseline_train``: the dataset whose train split gives the baseline's constants (default
    ``data_dir``; e.g. the model's training pool when ``data_dir`` holds only test scenes).

    Writes ``<out_dir>/scores.json`` and ``<out_dir>/table.md``; returns the scores.
    """
    from gspi.stage2.encoders import build_encoder
    from gspi.stage2.train import load_split
    from gspi.stage2.validate import ValidationConfig, subset_prediction

    run_cfg = {**cfg, "data_dir": str(data_dir)}
    stage2 = cfg["stage2"]
    encoder = build_encoder(stage2["prior"])
    data_cfg = PointDataConfig.from_mapping(stage2["data"])
    scenes = load_split(run_cfg, split, encoder)
    constants_cfg = run_cfg if baseline_train is None else {**cfg, "data_dir": str(baseline_train)}
    try:
        train_scenes = load_split(constants_cfg, "train", encoder)
    except ValueError as exc:  # e.g. a test-only dataset
        raise ValueError(f"{exc}: the no-decomposition baseline's roughness/metallic are training means; "
                         "pass a dataset with a train split (--baseline-train, e.g. the model's training "
                         "data)") from exc
    rough, metal = training_constants(train_scenes)

    sampling = ValidationConfig(num_steps=num_steps, max_points=max_points, seed=seed)

    def predict(scene: ScenePoints) -> np.ndarray:
        return subset_prediction(model, scene, scenes.index(scene), data_cfg, sampling, write_chunk=write_chunk)

    result = evaluate_scenes(scenes, predict, lambda s: baseline_prediction(s, rough, metal))
    result.update(format="gspi-points-eval", version=1, ablation=str(cfg.get("ablation_name", "full")),
                  train_seed=cfg.get("seed"), data=str(Path(data_dir).resolve()), **dict(source or {}),
                  split=split, num_steps=num_steps, max_points=max_points, seed=seed, scenes=[s.name for s in scenes],
                  baseline_constants={"roughness": rough, "metallic": metal},
                  baseline_train=str(Path(baseline_train or data_dir).resolve()), psnr_cap_db=PSNR_CAP_DB,
                  lpips="AlexNet LPIPS v0.1 (eval.lpips_net), masked_mean", encoder=stage2["prior"]["encoder"])
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out_dir / "scores.json", result, allow_nan=True)
    caption = (f"Stage II on the GT point clouds of {len(scenes)} {split} scenes of {Path(data_dir).name} "
               f"({num_steps} DDIM steps, seed {seed}); per-view masked metrics averaged over the 32 lattice "
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
    parser.add_argument("--max-points", type=int, default=None,
                        help="per scene: a seeded subset + 1-NN fill (the validation measure); default every point")
    parser.add_argument("--baseline-train", default=None,
                        help="dataset whose train split gives the baseline's constants (default: DATA)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(args.threads)
    model, cfg = load_stage2_checkpoint(args.checkpoint)
    evaluate_checkpoint(model, cfg, args.data, args.out, split=args.split, num_steps=args.num_steps, seed=args.seed,
                        source=checkpoint_source(args.checkpoint), max_points=args.max_points,
                        baseline_train=args.baseline_train)
    print((Path(args.out) / "table.md").read_text())


if __name__ == "__main__":
    main()
