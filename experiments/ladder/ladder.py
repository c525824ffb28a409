"""The learnability ladder: where Stage II loses the material signal (docs/STAGE2.md
"Where the signal is lost").

Rungs R1-R4 (``experiments.ladder.regressors``) are trained here as direct regressors of f0 on the
same batches as the diffusion model (local 512-point subsets of the perturbed GT clouds of the
training scenes, ``gspi.stage2.data``), with the Stage II recipe's optimiser, learning-rate
schedule, clipping and EMA (``stage2.train``), for ``--steps`` steps or ``--cpu-minutes`` of
this process's CPU time, whichever ends first. R0 (no decomposition) and R5 (the diffusion
model, ``gspi-train``) are scored by ``gspi.stage2.evaluate_points``; every rung is scored by the
same function (``evaluate_scenes``: Table 2's measure) and written in the same ``scores.json``
format, so ``python -m experiments.ladder.ladder summary`` and ``experiments.ladder.points_breakdown`` read them all.

    python -m experiments.ladder.ladder train --rung r1 --seed 0 --data POOL --out runs/ladder/r1_s0 \\
        --eval heldout=POOL:test --eval small=SMALL:test [--cpu-minutes 10] [--steps 4000]
    python -m experiments.ladder.ladder summary runs/ladder/*/eval_heldout
"""
from __future__ import annotations

import argparse
import copy
import json
import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch
from torch import Tensor, nn

from gspi.stage2.config import complete_stage2, stored_config
from gspi.stage2.data import (PointDataConfig, ScenePoints, local_condition, local_subset,
                              perturb_along_rays, sample_batch)
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.normalize import pbr_from_model, to_unit_sphere
from experiments.ladder.regressors import (MLP_RUNGS, PointMLP, RCWRegressor, point_features, pooled_prior,
                                    regression_loss, rung_features)

log = logging.getLogger(__name__)
LADDER_RECIPE = "table2_cpu"  # the Stage II recipe every rung shares (R5 is trained with it)
MLP_STEPS = 4000
RUNG_FORMAT = "gspi-ladder-rung"


def ladder_config(data_dir: str | Path, seed: int, overrides: tuple[str, ...] = ()) -> dict:
    """The resolved gspi-train config of the ladder's recipe (``stage2=table2_cpu``, Full)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from eval.common.conf import CONF_DIR

    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("gspi_train", overrides=[f"stage2={LADDER_RECIPE}", f"data_dir={data_dir}", "out=unused",
                                               f"seed={seed}", *overrides])
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain["stage2"] = complete_stage2(plain["stage2"])  # the checked Stage2Config
    return plain


def build_rung(rung: str, cfg: Mapping[str, Any], prior_dim: int) -> nn.Module:
    if rung in MLP_RUNGS:
        return PointMLP(rung_features(rung).width(prior_dim))
    if rung == "r4":
        from gspi.stage2.train import rcw_config

        return RCWRegressor(replace(rcw_config(cfg["stage2"], prior_dim), self_condition=False,
                                    cond_drop_prob=0.0, prediction="x0"))
    raise ValueError(f"rung {rung!r}: trained here are {sorted(MLP_RUNGS) + ['r4']}; r0 and r5 are "
                     "scored by gspi.stage2.evaluate_points")


def mlp_batch(scenes: list[ScenePoints], rung: str, data_cfg: PointDataConfig, batch_size: int,
              rng: np.random.Generator) -> tuple[Tensor, Tensor]:
    """(features [B * N, C], f0 [B * N, 5]) drawn as ``sample_batch`` draws (scene, subset, noise)."""
    spec = rung_features(rung)
    feats, f0 = [], []
    for _ in range(batch_size):
        scene = scenes[int(rng.integers(len(scenes)))]
        idx = local_subset(scene, data_cfg.num_points, rng)
        xyz = perturb_along_rays(scene.xyz[idx], scene.view[idx], scene.cameras,
                                 sigma_pixels=data_cfg.perturb_pixels, rng=rng)
        feats.append(point_features(scene, idx, xyz, spec, tol_pixels=data_cfg.visibility_tol_pixels))
        f0.append(torch.from_numpy(scene.f0[idx]))
    return torch.cat(feats), torch.cat(f0)


def rung_loss(model: nn.Module, rung: str, scenes: list[ScenePoints], data_cfg: PointDataConfig,
              batch_size: int, rng: np.random.Generator) -> Tensor:
    """The regression loss of one freshly drawn batch."""
    if rung in MLP_RUNGS:
        feats, f0 = mlp_batch(scenes, rung, data_cfg, batch_size, rng)
        return regression_loss(model(feats), f0)
    f0, inputs = sample_batch(scenes, data_cfg, batch_size, rng)
    return regression_loss(model(inputs), f0)


def train_rung(rung: str, cfg: Mapping[str, Any], scenes: list[ScenePoints], prior_dim: int, *,
               steps: int, cpu_minutes: float, metrics_path: Optional[Path] = None) -> tuple[nn.Module, dict]:
    """Trains a rung; returns (EMA model in eval mode, stats). Seeds follow gspi-train's."""
    from gspi.stage2.train import learning_rate, update_ema

    train = replace(cfg["stage2"].train, steps=int(steps))
    seed = int(cfg["seed"])
    torch.manual_seed(seed)
    model = build_rung(rung, cfg, prior_dim)
    ema = copy.deepcopy(model).requires_grad_(False).eval()
    opt = torch.optim.AdamW(model.parameters(), lr=float(train.lr), betas=tuple(train.betas),
                            weight_decay=float(train.weight_decay))
    rng = np.random.default_rng([seed, 1])
    data_cfg = cfg["stage2"].data
    cpu_end = time.process_time() + 60.0 * float(cpu_minutes)
    cpu0, wall0, losses = time.process_time(), time.perf_counter(), []
    log_file = None if metrics_path is None else open(metrics_path, "w")
    step = 0
    while step < steps and time.process_time() < cpu_end:
        for group in opt.param_groups:
            group["lr"] = learning_rate(step, train)
        model.train()
        loss = rung_loss(model, rung, scenes, data_cfg, int(train["batch_size"]), rng)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"rung {rung}: non-finite loss {float(loss)} at step {step}")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), float(train["grad_clip"]))
        opt.step()
        update_ema(ema, model, decay=float(train["ema_decay"]), step=step)
        step += 1
        losses.append(float(loss.detach()))
        if log_file is not None:
            log_file.write(json.dumps({"step": step, "key": "ladder/train/loss", "value": losses[-1]}) + "\n")
        if step % 250 == 0:
            log.info("rung %s step %d loss %.4f", rung, step, np.mean(losses[-50:]))
    if log_file is not None:
        log_file.close()
    stats = {"rung": rung, "seed": seed, "steps": step, "planned_steps": int(steps), "cpu_minutes_cap": cpu_minutes,
             "cpu_s": round(time.process_time() - cpu0, 1), "wall_s": round(time.perf_counter() - wall0, 1),
             "final_loss": float(np.mean(losses[-100:])) if losses else None,
             "parameters": sum(p.numel() for p in model.parameters())}
    return ema, stats


def save_rung(model: nn.Module, rung: str, cfg: Mapping[str, Any], stats: Mapping[str, Any], path: Path) -> Path:
    from gspi.stage2.checkpoint import save_atomic

    prior_dim = int(stats.get("prior_dim", 0))
    return save_atomic({"format": RUNG_FORMAT, "rung": rung, "prior_dim": prior_dim, "state_dict": model.state_dict(),
                        "config": stored_config(cfg), "stats": dict(stats)}, path)


def load_rung(path: str | Path) -> tuple[nn.Module, str, dict]:
    """(EMA model in eval mode, rung, config) of a ``model.pt`` the ladder wrote; errors name the file."""
    from gspi.stage2.checkpoint import CheckpointError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such ladder model")
    saved = torch.load(path, map_location="cpu", weights_only=False)
    if not isinstance(saved, dict) or saved.get("format") != RUNG_FORMAT:
        raise CheckpointError(f"{path}: not a ladder model (format {RUNG_FORMAT!r})")
    cfg = {**saved["config"], "stage2": complete_stage2(saved["config"]["stage2"])}
    model = build_rung(saved["rung"], cfg, int(saved["prior_dim"]))
    try:
        model.load_state_dict(saved["state_dict"])
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: weights do not fit rung {saved['rung']}: {exc}") from exc
    return model.requires_grad_(False).eval(), saved["rung"], cfg


def eval_features(scene: ScenePoints, index: int, data_cfg: PointDataConfig, seed: int = 0) -> np.ndarray:
    """The evaluation's perturbed positions of every point: the draw ``subset_prediction`` makes."""
    rng = np.random.default_rng([seed, index])
    return perturb_along_rays(scene.xyz, scene.view, scene.cameras, sigma_pixels=data_cfg.perturb_pixels, rng=rng)


@torch.no_grad()
def predict_rung(model: nn.Module, rung: str, scene: ScenePoints, index: int, data_cfg: PointDataConfig,
                 *, chunk: int = 65536) -> np.ndarray:
    """[P, 5] PBR in [0, 1] of every point of ``scene`` (one forward pass, all 32 views)."""
    xyz = eval_features(scene, index, data_cfg)
    idx = np.arange(scene.num_points)
    if rung in MLP_RUNGS:
        spec = rung_features(rung)
        out = [model(point_features(scene, idx[s:s + chunk], xyz[s:s + chunk], spec,
                                    tol_pixels=data_cfg.visibility_tol_pixels))
               for s in range(0, scene.num_points, chunk)]
        return pbr_from_model(torch.cat(out)).numpy()
    cond = local_condition(scene, idx, xyz, data_cfg.local_condition, tol_pixels=data_cfg.visibility_tol_pixels)
    tokens = None if scene.global_tokens is None else scene.global_tokens.float()[None]
    inputs = Stage2Inputs(xyz=to_unit_sphere(torch.from_numpy(xyz), scene.frame).float()[None],
                          local_cond=torch.from_numpy(cond.astype(np.float32))[None], global_tokens=tokens)
    return pbr_from_model(model(inputs, write_chunk=32768)[0]).numpy()


def score_rung(model: nn.Module, rung: str, cfg: Mapping[str, Any], data_dir: str | Path, split: str,
               out_dir: Path, *, baseline_train: str | Path, train_stats: Mapping[str, Any]) -> dict:
    """Table 2's measure of a trained rung on ``split`` of ``data_dir``; writes scores.json."""
    from gspi.stage2.evaluate_points import score_split

    data_cfg = cfg["stage2"].data
    return score_split(lambda scene, index: predict_rung(model, rung, scene, index, data_cfg), cfg, data_dir,
                       split, out_dir, baseline_train=baseline_train,
                       record={"ablation": rung, "checkpoint": f"ladder:{rung}:seed{cfg['seed']}", "num_steps": None,
                               "max_points": None, "seed": 0, "ladder": dict(train_stats)})


def _eval_sets(specs: list[str]) -> list[tuple[str, str, str]]:
    out = []
    for spec in specs:
        name, _, rest = spec.partition("=")
        data, _, split = rest.rpartition(":")
        if not name or not data or not split:
            raise SystemExit(f"--eval {spec!r}: expected NAME=DATA_DIR:SPLIT")
        out.append((name, data, split))
    return out


def run_train(args: argparse.Namespace) -> None:
    from eval.common.atomic import write_json_atomic
    from gspi.stage2.encoders import build_encoder
    from gspi.stage2.splits import load_split

    cfg = ladder_config(args.data, args.seed, tuple(args.override))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    encoder = build_encoder(cfg["stage2"].prior)
    scenes = load_split(cfg, "train", encoder)
    prior_dim = 0 if scenes[0].global_tokens is None else int(pooled_prior(scenes[0]).shape[0])
    steps = args.steps or (MLP_STEPS if args.rung in MLP_RUNGS else int(cfg["stage2"].train.steps))
    model, stats = train_rung(args.rung, cfg, scenes, prior_dim, steps=steps, cpu_minutes=args.cpu_minutes,
                              metrics_path=out / "metrics.jsonl")
    stats["prior_dim"] = prior_dim
    save_rung(model, args.rung, cfg, stats, out / "model.pt")
    write_json_atomic(out / "stats.json", stats)
    log.info("trained %s: %s", args.rung, stats)
    for name, data, split in _eval_sets(args.eval):
        result = score_rung(model, args.rung, cfg, data, split, out / f"eval_{name}",
                            baseline_train=args.data, train_stats=stats)
        log.info("%s %s: avg PSNR %.2f (no decomposition %.2f)", args.rung, name,
                 result["mean"]["stage2"]["avg"]["psnr"], result["mean"]["no_decomposition"]["avg"]["psnr"])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train", help="train one rung (r1-r4) and score it")
    tr.add_argument("--rung", required=True, choices=sorted(MLP_RUNGS) + ["r4"])
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--data", required=True, help="training dataset (its train split)")
    tr.add_argument("--out", required=True)
    tr.add_argument("--eval", action="append", default=[], help="NAME=DATA_DIR:SPLIT (repeatable)")
    tr.add_argument("--steps", type=int, default=None, help=f"default: {MLP_STEPS} (MLP), the recipe's (r4)")
    tr.add_argument("--cpu-minutes", type=float, default=10.0)
    tr.add_argument("--threads", type=int, default=1)
    tr.add_argument("override", nargs="*", help="gspi-train overrides, e.g. stage2.train.lr=3e-4")
    sm = sub.add_parser("summary", help="per-rung table over seeds, per channel and material class")
    sm.add_argument("folders", nargs="+")
    sm.add_argument("--versus", default=None, help="also: paired difference of each rung to this one (e.g. r5)")
    sm.add_argument("--key", default="avg", help="with --versus: avg | albedo | roughness | metallic")
    sm.add_argument("--class", dest="scene_class", default=None, help="with --versus: only scenes of this class")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    if args.command == "train":
        torch.set_num_threads(args.threads)
        run_train(args)
    else:
        from experiments.ladder.ladder_summary import print_summary, versus

        folders = [Path(f) for f in args.folders]
        print_summary(folders)
        if args.versus:
            print(f"{args.key} PSNR minus {args.versus}'s, paired over (scene, seed), 95 % bootstrap CI"
                  + (f", {args.scene_class} scenes" if args.scene_class else "") + ":")
            for rung, (mean, lo, hi) in versus(folders, args.versus, args.key, args.scene_class).items():
                print(f"  {rung}: {mean:+.2f} [{lo:+.2f}, {hi:+.2f}]")


if __name__ == "__main__":
    main()
