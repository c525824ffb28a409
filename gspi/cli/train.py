"""gspi-train: train the Stage II denoiser, then score it on the test point clouds.

Examples:
    gspi-train data=RPOOL224 out=runs/s2 stage2=cpu_pool224_pixel_5k      # the shipped default's recipe
    gspi-train data=RPOOL64 out=runs/a2 stage2=table2_cpu ablation=a2_no_view_onehot   # one Table 2 row
    gspi-train data=data/tiny out=/tmp/s2 stage2=tiny                      # seconds (smoke run)
    gspi-train data=data/paper out=runs/s2 stage2.prior.encoder=dinov2 stage2.prior.dinov2.path=models/dinov2-base
    gspi-train data=RPOOL224 out=runs/s2 stage2=cpu_pool224_pixel_5k stage2.train.steps=8000   # resumes

Several GPUs (docs/REPRODUCE.md): `torchrun --nproc_per_node=4 -m gspi.cli.train ... device=cuda`
(data-parallel, the same global batch; gspi/stage2/distributed.py).

Rerunning with the same `out` resumes from `<out>/checkpoint.pt` (model, EMA, optimizer, step,
RNG states). Writes checkpoint.pt, metrics.jsonl, loss_curve.png, stats.json and (if
stage2.eval.enabled) eval_points/{scores.json,table.md} into `out`, which is also Hydra's run
dir (`<out>/.hydra/`). Config: conf/gspi_train.yaml, conf/stage2/, conf/ablation/.
"""
from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli

log = logging.getLogger(__name__)
# `data=<dir>` is an alias of the key `data_dir=<dir>`: conf/data/ is a config group (dataset
# presets), so Hydra would read `data=...` as a group override. `main` rewrites the argument.


def run(cfg: DictConfig) -> dict:
    """Trains (or resumes) Stage II into ``cfg.out`` and evaluates it; returns stats.json's content."""
    import torch

    from gspi.stage2.checkpoint import load_stage2_checkpoint
    from gspi.stage2.config import complete_stage2
    from gspi.stage2.evaluate_points import checkpoint_source, evaluate_checkpoint
    from gspi.device import resolve_device
    from gspi.stage2.distributed import from_env, shutdown
    from gspi.stage2.train import train

    from eval.common.atomic import write_json_atomic
    from gspi.strict_config import check_value

    check_value("threads", cfg.threads, int, lo=1, hi=1024)
    check_value("seed", cfg.seed, int, lo=0)
    dist = from_env(resolve_device(cfg.get("device", "cpu")))  # torchrun: one rank per GPU
    torch.set_num_threads(int(cfg.threads))
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("hydra", None)
    plain["stage2"] = complete_stage2(plain["stage2"])  # an unknown or ill-typed key fails here
    out = Path(cfg.out)
    # stats.json is the run's record, written last: an earlier one must not outlive a killed rerun
    if dist.is_main:
        (out / "stats.json").unlink(missing_ok=True)
    stats = train(plain, out, dist=dist)  # budgets: stage2.train.stop_at / stop_after_(cpu_)minutes
    if not dist.is_main:  # rank 0 evaluates and writes the record
        shutdown(dist)
        return stats
    shutdown(dist)
    ev = plain["stage2"].eval
    if ev.enabled:
        model, saved_cfg = load_stage2_checkpoint(out / "checkpoint.pt")
        result = evaluate_checkpoint(model, saved_cfg, plain["data_dir"], out / "eval_points", split=ev.split,
                                     num_steps=ev.num_steps, seed=ev.seed, write_chunk=ev.write_chunk,
                                     source=checkpoint_source(out / "checkpoint.pt"))
        stats["eval_points"] = {"split": ev.split, "mean": result["mean"]}
    write_json_atomic(out / "stats.json", stats, allow_nan=True)
    log.info("wrote %s", out / "stats.json")
    return stats


def _task(cfg: DictConfig) -> float | None:
    stats = run(cfg)
    return stats.get("final_loss")


# paths quoted for Hydra's grammar, stated errors as one line
main = hydra_cli(_task, "gspi_train", path_keys=("data_dir", "out"))


if __name__ == "__main__":
    main()
