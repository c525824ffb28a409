"""Stage II training (paper Sec. "Training vs. Inference Dynamics"): eps-prediction with the
cosine schedule and Min-SNR-gamma weighting (``gspi.stage2.loss.denoising_loss``) on local
512-point subsets of perturbed GT point clouds (``gspi.stage2.data``), AdamW with linear
warm-up and cosine decay, gradient clipping, an EMA of the weights, periodic checkpoints
that a rerun resumes from exactly (whole-cloud inference: ``gspi.stage2.sampler.predict_point_pbr``).

``cfg`` is the resolved ``gspi-train`` config as a dict (``conf/gspi_train.yaml``): ``data_dir``
(dataset dir), ``out``, ``seed`` and ``stage2``, which ``train`` turns into the checked
``gspi.stage2.config.Stage2Config`` first; everything below reads its fields.
"""
from __future__ import annotations

import copy
import logging
import math
import time
from pathlib import Path
from typing import Any, Mapping, Optional

import numpy as np
import torch
from torch import Tensor

from eval.records.eval_folder import environment_info
from gspi.stage2.checkpoint import (CheckpointError, ema_only, load_weights, rcw_config_dict,
                                    read_checkpoint, save_atomic, CHECKPOINT_FORMAT, CHECKPOINT_VERSION)
from gspi.stage2.config import TrainConfig, complete_stage2, stored_config
from gspi.stage2.distributed import DistContext
from gspi.stage2.data import sample_batch
from gspi.stage2.encoders import build_encoder
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.loss import denoising_loss
from gspi.stage2.model import RCWConfig, RCWDenoiser, count_parameters
from gspi.stage2.schedule import cosine_alphas_cumprod
from gspi.stage2.splits import load_split
from gspi.stage2.train_log import JsonlMetrics, plot_loss_curve

log = logging.getLogger(__name__)
LOSS_KEY = "stage2/train/loss"


def rcw_config(stage2, global_token_dim: int) -> RCWConfig:
    """RCWConfig from ``stage2.model`` (a Stage2Config or its node); the condition widths follow
    ``stage2.data`` and the encoder."""
    stage2 = complete_stage2(stage2)
    local, diffusion = stage2.data.local_condition, stage2.diffusion
    return RCWConfig(**stage2.model, local_cond_dim=stage2.data.condition_width(global_token_dim),
                     use_view_onehot=local == "top_rgb_onehot", global_token_dim=global_token_dim,
                     prediction=diffusion.prediction, num_train_timesteps=diffusion.num_train_timesteps,
                     readout_column=stage2.data.light_readout_column() if diffusion.prediction == "x0_readout" else None,
                     readout_metal_gate=diffusion.readout_metal_gate)


def learning_rate(step: int, train: TrainConfig) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine decay to ``min_lr_ratio * lr``."""
    lr, warmup, total = float(train.lr), int(train.warmup_steps), int(train.steps)
    if step < warmup:
        return lr * (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    ratio = float(train.min_lr_ratio)
    return lr * (ratio + (1.0 - ratio) * 0.5 * (1.0 + math.cos(math.pi * progress)))


@torch.no_grad()
def update_ema(ema: torch.nn.Module, model: torch.nn.Module, *, decay: float, step: int) -> None:
    """``ema <- d ema + (1 - d) model`` with warm-up ``d = min(decay, (1 + step) / (10 + step))``
    (diffusers ``EMAModel``): early averages are not dominated by the random init. Hand-written
    because torch's AveragedModel has no warm-up."""
    d = min(decay, (1.0 + step) / (10.0 + step))
    ema_params, params = list(ema.parameters()), list(model.parameters())
    torch._foreach_lerp_(ema_params, params, 1.0 - d)


class TrainState:
    """Model, EMA copy, optimizer, step and the RNGs that make a resumed run continue exactly."""

    def __init__(self, cfg: Mapping[str, Any], model_config: RCWConfig):
        train = cfg["stage2"].train
        torch.manual_seed(int(cfg["seed"]))
        self.model = RCWDenoiser(model_config)
        self.ema = copy.deepcopy(self.model).requires_grad_(False).eval()
        self.optimizer = torch.optim.AdamW(self.model.parameters(), lr=float(train.lr),
                                           betas=tuple(train.betas), weight_decay=float(train.weight_decay))
        self.step = 0
        self.elapsed_s = 0.0
        self.best: dict = {}  # {"step", "score"} of the best validation so far (best.pt)
        self.data_rng = np.random.default_rng([int(cfg["seed"]), 1])
        self.loss_generator = torch.Generator().manual_seed(int(cfg["seed"]) + 2)

    def state_dict(self, cfg: Mapping[str, Any]) -> dict:
        return {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "step": self.step,
                "rcw_config": rcw_config_dict(self.model.config), "config": stored_config(cfg),
                "model": self.model.state_dict(), "ema": self.ema.state_dict(),
                "optimizer": self.optimizer.state_dict(), "elapsed_s": self.elapsed_s, "best": self.best,
                "rng": {"numpy": self.data_rng.bit_generator.state, "loss": self.loss_generator.get_state(),
                        "torch": torch.get_rng_state()}}

    def load(self, path: Path) -> None:
        """Restores everything from a training checkpoint (errors name the file)."""
        ckpt = read_checkpoint(path)
        if ckpt["rcw_config"] != rcw_config_dict(self.model.config):
            raise CheckpointError(f"{path}: model config {ckpt['rcw_config']} differs from this run's "
                                  f"{rcw_config_dict(self.model.config)}; use another out dir")
        for key in ("model", "optimizer", "rng"):
            if key not in ckpt:
                raise CheckpointError(f"{path}: not a training checkpoint (no {key!r}); cannot resume")
        load_weights(self.model, ckpt["model"], path, "model")
        load_weights(self.ema, ckpt["ema"], path, "EMA")
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.step, self.elapsed_s = int(ckpt["step"]), float(ckpt.get("elapsed_s", 0.0))
        self.best = dict(ckpt.get("best") or {})  # absent in checkpoints written before validation
        self.data_rng.bit_generator.state = ckpt["rng"]["numpy"]
        self.loss_generator.set_state(ckpt["rng"]["loss"])
        torch.set_rng_state(ckpt["rng"]["torch"])


def train_step(state: TrainState, f0: Tensor, inputs: Stage2Inputs, cfg: Mapping[str, Any],
               alphas_cumprod: Tensor, dist: DistContext = DistContext()) -> dict[str, float]:
    """One AdamW step on one batch (this rank's slice under ``dist``); updates the EMA.
    Returns the logged scalars (the loss averaged over ranks)."""
    train, diffusion = cfg["stage2"].train, cfg["stage2"].diffusion
    lr = learning_rate(state.step, train)
    for group in state.optimizer.param_groups:
        group["lr"] = lr
    state.model.train()
    loss = denoising_loss(state.model, f0, inputs, generator=state.loss_generator, alphas_cumprod=alphas_cumprod,
                          min_snr_gamma=float(diffusion.min_snr_gamma),
                          min_snr_floor=float(diffusion.min_snr_floor),
                          self_condition_prob=float(diffusion.self_condition_prob), shard=dist.loss_shard)
    if not torch.isfinite(loss):
        raise FloatingPointError(f"non-finite Stage II loss {float(loss)} at step {state.step}")
    state.optimizer.zero_grad(set_to_none=True)
    loss.backward()
    dist.average_gradients(state.model)
    grad_norm = torch.nn.utils.clip_grad_norm_(state.model.parameters(), float(train.grad_clip))
    state.optimizer.step()
    update_ema(state.ema, state.model, decay=float(train.ema_decay), step=state.step)
    state.step += 1
    return {LOSS_KEY: dist.mean(float(loss.detach())), "stage2/train/grad_norm": float(grad_norm), "stage2/train/lr": lr}


class _NoMetrics:
    """metrics.jsonl of a rank other than 0: nothing is written."""

    def log(self, step, values) -> None:
        pass

    def truncate_after(self, step) -> None:
        pass


def save_checkpoint(state: TrainState, cfg: Mapping[str, Any], out_dir: Path) -> Path:
    return save_atomic(state.state_dict(cfg), out_dir / "checkpoint.pt")


def append_run_log(path: str | Path, out_dir: Path, stats: dict, *, cpu_s: float, commit: Optional[str]) -> Path:
    """One JSON line per finished run (or chunk of a long recipe) in ``stage2.train.run_log``
    (relative paths: the repository's), so what a cut-off session finished is on record.
    ``commit``: the repository's commit when the run started (the code that ran; the checkout
    may have moved on by the time a long chunk ends)."""
    import datetime
    import json

    from eval.portable import portable_path

    from gspi.repo import REPO as repo

    path = Path(path)
    if not path.is_absolute():
        path = repo / path
    path.parent.mkdir(parents=True, exist_ok=True)
    # the log is committed: a run under the repository by its relative path, any other by
    # "<elsewhere>/<last two parts>" (no machine path in a tracked file, tests/test_portable_paths.py)
    out_text = portable_path(str(Path(out_dir).resolve()), {"": repo})
    line = {"finished": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "out": out_text, "commit": commit, "seed": stats["seed"],
            "steps": [stats["resumed_from"], stats["steps"]], "of": stats["total_steps"],
            "done": stats["steps"] >= stats["total_steps"], "wall_s_total": stats["wall_time_s"],
            "cpu_s_this_run": round(cpu_s, 1), "final_loss": stats["final_loss"]}
    with open(path, "a") as f:
        f.write(json.dumps(line) + "\n")
    return path


class Budget:
    """Wall-clock and process-CPU-time limits of one run (None = no limit)."""

    def __init__(self, wall_minutes: Optional[float], cpu_minutes: Optional[float]):
        self.wall_end = None if wall_minutes is None else time.perf_counter() + 60.0 * float(wall_minutes)
        self.cpu_end = None if cpu_minutes is None else time.process_time() + 60.0 * float(cpu_minutes)

    def exclude(self, cpu_s: float, wall_s: float) -> None:
        """Time spent on something else than training (validation) does not count."""
        self.wall_end = None if self.wall_end is None else self.wall_end + wall_s
        self.cpu_end = None if self.cpu_end is None else self.cpu_end + cpu_s

    def spent(self) -> bool:
        return (self.wall_end is not None and time.perf_counter() >= self.wall_end) or \
            (self.cpu_end is not None and time.process_time() >= self.cpu_end)


class CheckpointClock:
    """Due when ``minutes`` of wall-clock time passed since the last checkpoint (None: never), so a
    session cut off without warning loses at most that much training."""

    def __init__(self, minutes: Optional[float]):
        self.seconds = None if minutes is None else 60.0 * float(minutes)
        self.restart()

    def restart(self) -> None:
        self.last = time.perf_counter()

    def due(self) -> bool:
        return self.seconds is not None and time.perf_counter() - self.last >= self.seconds


def make_validator(cfg: Mapping[str, Any], encoder):
    """The run's Validator, or None when ``stage2.validate.every`` is null."""
    from gspi.stage2.validate import Validator

    vcfg = cfg["stage2"].validate
    if vcfg.every is None:
        return None
    source = {**cfg, "data_dir": vcfg.data} if vcfg.data else cfg
    return Validator(vcfg, load_split(source, vcfg.split, encoder), cfg["stage2"].data)


def validate(state: TrainState, validator, cfg: Mapping[str, Any], out_dir: Path, metrics) -> dict:
    """Scores the EMA weights, logs the scores at this step; a new best is written as best.pt
    (EMA-only, loadable wherever a Stage II checkpoint is)."""
    from gspi.stage2.validate import SCORE_KEY

    t0 = time.perf_counter()
    scores = validator.score(state.ema)
    metrics.log(state.step, {**scores, "stage2/val/seconds": time.perf_counter() - t0})
    if not state.best or scores[SCORE_KEY] > state.best["score"]:
        state.best = {"step": state.step, "score": scores[SCORE_KEY]}
        save_atomic({**ema_only(state.state_dict(cfg)), "best": state.best}, out_dir / "best.pt")
    log.info("step %d  validation avg PSNR %.2f dB (best %.2f at step %d)", state.step, scores[SCORE_KEY],
             state.best["score"], state.best["step"])
    return scores


def train(cfg: Mapping[str, Any], out_dir: str | Path, *, stop_at: Optional[int] = None,
          stop_after_minutes: Optional[float] = None, stop_after_cpu_minutes: Optional[float] = None,
          dist: DistContext = DistContext()) -> dict:
    """Trains (or resumes from ``<out>/checkpoint.pt``) up to ``stage2.train.steps``; the
    three budgets default to ``stage2.train``'s (``stop_at``, ``stop_after_minutes``,
    ``stop_after_cpu_minutes``), a value passed here takes their place.

    Writes ``checkpoint.pt`` (every ``checkpoint_every`` steps and at the end),
    ``metrics.jsonl`` and ``loss_curve.png``. Returns the run statistics.

    Args:
        stop_at: checkpoint and return after this step (an interruption that a rerun resumes
            from; the schedule still follows ``steps``).
        stop_after_minutes: the same, once this run has trained this many wall-clock minutes
            (a CPU budget; chain runs through the exact resume).
        stop_after_cpu_minutes: the same after this many minutes of this process's CPU time
            (all its threads): a budget that other jobs on the machine do not shrink, so runs
            compared "for the same CPU time" are, whatever else ran beside them.
        dist: this process's rank, world size and device (gspi.stage2.distributed); rank 0
            alone writes. The default is one CPU process, the plain run.
    """
    out_dir = Path(out_dir)
    cfg = {**cfg, "stage2": complete_stage2(cfg["stage2"])}  # checked; every key present
    stage2 = cfg["stage2"]
    train_cfg, data_cfg = stage2.train, stage2.data
    encoder = build_encoder(stage2.prior)
    scenes = load_split(cfg, "train", encoder)
    validator = make_validator(cfg, encoder) if dist.is_main else None
    stop_at = train_cfg.stop_at if stop_at is None else stop_at
    stop_after_minutes = train_cfg.stop_after_minutes if stop_after_minutes is None else stop_after_minutes
    stop_after_cpu_minutes = (train_cfg.stop_after_cpu_minutes if stop_after_cpu_minutes is None
                              else stop_after_cpu_minutes)
    state = TrainState(cfg, rcw_config(stage2, encoder.feature_dim))
    if dist.device.type != "cpu":
        state.model.to(dist.device), state.ema.to(dist.device)
    dist.local_batch(int(train_cfg.batch_size))  # divisible by the ranks, checked before any step
    metrics = JsonlMetrics(out_dir / "metrics.jsonl") if dist.is_main else _NoMetrics()
    ckpt_path = out_dir / "checkpoint.pt"
    if ckpt_path.is_file():
        state.load(ckpt_path)
        metrics.truncate_after(state.step)
        log.info("resumed from %s at step %d", ckpt_path, state.step)
    else:
        metrics.truncate_after(-1)
        init_from = train_cfg.init_from
        if init_from:  # fine-tuning: weights (not optimizer or step) of another Stage II model
            from gspi.repo import REPO
            from gspi.stage2.checkpoint import read_checkpoint, load_weights

            init_from = Path(init_from)
            if not init_from.exists() and not init_from.is_absolute():  # relative to the repository
                init_from = REPO / init_from
            src = read_checkpoint(init_from)
            weights = src.get("ema") or src.get("model")
            load_weights(state.model, weights, init_from, "init_from")
            load_weights(state.ema, weights, init_from, "init_from")
            log.info("initialised the weights from %s", init_from)
    alphas_cumprod = cosine_alphas_cumprod(int(stage2.diffusion.num_train_timesteps)).to(dist.device)
    total, every = int(train_cfg.steps), int(train_cfg.checkpoint_every)
    log_every = int(train_cfg.log_every)
    start_step, t0, validated_at = state.step, time.perf_counter(), None
    end = total if stop_at is None else min(total, int(stop_at))
    budget = Budget(stop_after_minutes, stop_after_cpu_minutes)
    checkpoint_clock = CheckpointClock(train_cfg.checkpoint_minutes)
    cpu0 = time.process_time()
    commit = environment_info()["git_commit"] if train_cfg.run_log else None  # the code this run starts from
    while state.step < end and not dist.any(budget.spent()):
        f0, inputs = dist.shard(*sample_batch(scenes, data_cfg, int(train_cfg.batch_size), state.data_rng))
        values = train_step(state, f0, inputs, cfg, alphas_cumprod, dist)
        metrics.log(state.step, values)
        if state.step % log_every == 0:
            log.info("step %d  loss %.4f  lr %.2e", state.step, values[LOSS_KEY], values["stage2/train/lr"])
        if validator is not None and validator.due(state.step, end):
            c0, w0 = time.process_time(), time.perf_counter()
            validate(state, validator, cfg, out_dir, metrics)
            budget.exclude(time.process_time() - c0, time.perf_counter() - w0)
            validated_at = state.step
        if (state.step % every == 0 or checkpoint_clock.due()) and state.step < end:
            state.elapsed_s += time.perf_counter() - t0
            t0 = time.perf_counter()
            checkpoint_clock.restart()
            if dist.is_main:
                save_checkpoint(state, cfg, out_dir)
    if validator is not None and state.step > start_step and validated_at != state.step:
        validate(state, validator, cfg, out_dir, metrics)  # stopped early (stop_after_minutes)
    state.elapsed_s += time.perf_counter() - t0
    if dist.is_main and (state.step > start_step or not ckpt_path.is_file()):
        save_checkpoint(state, cfg, out_dir)
    dist.barrier()
    if not dist.is_main:
        return {"steps": state.step, "rank": dist.rank}
    plot_loss_curve(metrics, out_dir / "loss_curve.png")
    _, losses = metrics.series(LOSS_KEY)
    stats = {"steps": state.step, "total_steps": total, "resumed_from": start_step, "wall_time_s": round(state.elapsed_s, 2),
             "final_loss": float(losses[-100:].mean()) if len(losses) else None,
             "parameters": count_parameters(state.model), "seed": int(cfg["seed"]),
             "num_train_scenes": len(scenes), "global_token_dim": encoder.feature_dim,
             "best_validation": state.best or None}
    if train_cfg.run_log:
        append_run_log(train_cfg.run_log, out_dir, stats, cpu_s=time.process_time() - cpu0, commit=commit)
    return stats
