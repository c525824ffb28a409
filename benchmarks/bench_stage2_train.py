"""Stage II training throughput (points/s, steps/s) of the shipped CPU model, per setting.

One AdamW step = ``gspi.stage2.train.train_step`` (loss, backward, clipping, step, EMA) on a
fixed synthetic batch shaped like ``sample_batch``'s (N = stage2.data.num_points points per item,
the recipe's local condition (35 dims, + 256 with ``stage2.data.pixel_features``), 16 of 32 prior
views x 25 tokens x 256 AlexNet dims), so the figure is the model's compute. The model timed is
gspi-run's default recipe (conf/gspi_run.yaml's ``stage2``) unless ``--stage2`` names another;
``--data`` also times ``sample_batch`` on a dataset's training scenes.

    python -m benchmarks.bench_stage2_train                       # threads {1, 2} x batch {8, 32}
    python -m benchmarks.bench_stage2_train --settings 1x8 2x32 --compile
    python -m benchmarks.bench_stage2_train --data ~/.cache/gspi/stage2_pool
    python -m benchmarks.bench_stage2_train --settings 1x32 2x32 2px1x32   # + data-parallel
    python -m benchmarks.bench_stage2_train --settings 1x16 --stage2 capacity_l   # another size

A setting ``TxB`` = T torch threads, global batch B; ``PpxTxB`` = P data-parallel processes
(``gspi.stage2.distributed`` on gloo, as ``torchrun --nproc_per_node=P`` runs gspi-train) of T
threads each, global batch B. Medians over ``--repeats`` steps after a warm-up.
"""
from __future__ import annotations

import argparse
import os
import socket
import time
from pathlib import Path

import numpy as np
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from benchmarks.common import machine, median_seconds
from gspi.stage2.config import complete_stage2
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.schedule import cosine_alphas_cumprod
from gspi.stage2.train import TrainState, rcw_config, train_step

CONF = Path(__file__).resolve().parents[1] / "conf"
PRIOR_DIM, VIEWS_KEPT, CELLS = 256, 16, 25




def run_default_recipe() -> str:
    """The stage2 option gspi-run uses (conf/gspi_run.yaml): the shipped model's recipe."""
    import yaml

    defaults = yaml.safe_load((CONF / "gspi_run.yaml").read_text())["defaults"]
    return next(d["stage2"] for d in defaults if isinstance(d, dict) and "stage2" in d)


STAGE2 = {"config": run_default_recipe()}  # --stage2: the model timed (conf/stage2/<name>.yaml)


def train_config(overrides: list[str]) -> dict:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("gspi_train", overrides=[f"stage2={STAGE2['config']}", "data_dir=.", "out=.",
                                               "stage2.train.init_from=null", *overrides])
    plain = OmegaConf.to_container(cfg, resolve=True)
    return {**plain, "stage2": complete_stage2(plain["stage2"])}


def synthetic_batch(batch: int, num_points: int, cond_dim: int, seed: int = 0) -> tuple[torch.Tensor, Stage2Inputs]:
    g = torch.Generator().manual_seed(seed)
    f0 = torch.rand(batch, num_points, 5, generator=g) * 2 - 1
    inputs = Stage2Inputs(xyz=torch.nn.functional.normalize(torch.randn(batch, num_points, 3, generator=g), dim=-1),
                          local_cond=torch.rand(batch, num_points, cond_dim, generator=g),
                          global_tokens=torch.randn(batch, VIEWS_KEPT, CELLS, PRIOR_DIM, generator=g),
                          view_ids=torch.stack([torch.randperm(32, generator=g)[:VIEWS_KEPT].sort().values
                                                for _ in range(batch)]))
    return f0, inputs


def time_setting(threads: int, batch: int, *, repeats: int, compile_model: bool) -> dict:
    torch.set_num_threads(threads)
    cfg = train_config([f"stage2.train.batch_size={batch}"])
    state = TrainState(cfg, rcw_config(cfg["stage2"], PRIOR_DIM))
    if compile_model:
        state.model = torch.compile(state.model)
    n = int(cfg["stage2"].data.num_points)
    f0, inputs = synthetic_batch(batch, n, state.model.config.local_cond_dim if not compile_model
                                 else state.model._orig_mod.config.local_cond_dim)
    alphas = cosine_alphas_cumprod(int(cfg["stage2"].diffusion.num_train_timesteps))
    t0 = time.perf_counter()
    train_step(state, f0, inputs, cfg, alphas)          # warm-up (and compilation)
    first = time.perf_counter() - t0
    sec = median_seconds(lambda: train_step(state, f0, inputs, cfg, alphas), repeats=repeats, warmup=0)
    return {"threads": threads, "batch": batch, "compile": compile_model, "s_per_step": sec,
            "steps_per_s": 1 / sec, "points_per_s": batch * n / sec, "first_step_s": first}


def _ddp_worker(rank: int, world: int, port: int, threads: int, batch: int, repeats: int, queue) -> None:
    import torch.distributed as dist

    from gspi.stage2.distributed import DistContext

    torch.set_num_threads(threads)
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("gloo", rank=rank, world_size=world)
    ctx = DistContext(rank=rank, world_size=world)
    cfg = train_config([f"stage2.train.batch_size={batch}"])
    state = TrainState(cfg, rcw_config(cfg["stage2"], PRIOR_DIM))
    f0, inputs = ctx.shard(*synthetic_batch(batch, int(cfg["stage2"].data.num_points),
                                            state.model.config.local_cond_dim))
    alphas = cosine_alphas_cumprod(int(cfg["stage2"].diffusion.num_train_timesteps))
    train_step(state, f0, inputs, cfg, alphas, ctx)      # warm-up
    sec = median_seconds(lambda: train_step(state, f0, inputs, cfg, alphas, ctx), repeats=repeats, warmup=0)
    if rank == 0:
        queue.put(sec)
    dist.destroy_process_group()


def time_ddp(procs: int, threads: int, batch: int, *, repeats: int) -> dict:
    """Global points/s of ``procs`` gloo processes sharing the global batch (fork start)."""
    import torch.multiprocessing as mp

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    queue = mp.get_context("fork").SimpleQueue()
    mp.start_processes(_ddp_worker, args=(procs, port, threads, batch, repeats, queue), nprocs=procs,
                       join=True, start_method="fork")
    sec = queue.get()
    n = int(train_config([])["stage2"].data.num_points)
    return {"threads": threads, "procs": procs, "batch": batch, "compile": False, "s_per_step": sec,
            "steps_per_s": 1 / sec, "points_per_s": batch * n / sec, "first_step_s": float("nan")}


def time_sampling(data_dir: str, batch: int, repeats: int) -> float:
    from gspi.stage2.data import sample_batch
    from gspi.stage2.encoders import build_encoder
    from gspi.stage2.splits import load_split

    cfg = train_config([f"data_dir={data_dir}"])
    scenes = load_split(cfg, "train", build_encoder(cfg["stage2"].prior))
    data_cfg = cfg["stage2"].data
    rng = np.random.default_rng(0)
    return median_seconds(lambda: sample_batch(scenes, data_cfg, batch, rng), repeats=repeats)


def parse_setting(text: str) -> tuple[int, int, int]:
    """"TxB" -> (1, T, B); "PpxTxB" -> (P, T, B)."""
    procs = 1
    if "p" in text:
        head, text = text.split("px", 1)
        procs = int(head)
    threads, batch = (int(x) for x in text.split("x"))
    return procs, threads, batch


def label(r: dict) -> str:
    procs = f"{r['procs']}px" if r.get("procs", 1) > 1 else ""
    return f"{procs}{r['threads']}x{r['batch']}{' compiled' if r['compile'] else ''}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settings", nargs="+", default=["1x8", "2x8", "1x32", "2x32"],
                        help="THREADSxBATCH settings to time")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--compile", action="store_true", help="also time torch.compile (inductor)")
    parser.add_argument("--data", default=None, help="dataset folder: also time sample_batch")
    parser.add_argument("--stage2", default=STAGE2["config"], help="conf/stage2 config of the model timed "
                        "(default: gspi-run's)")
    args = parser.parse_args()
    STAGE2["config"] = args.stage2
    print(f"machine: {machine()}; model: stage2={args.stage2}")
    rows = []
    for setting in args.settings:
        procs, threads, batch = parse_setting(setting)
        if procs > 1:
            rows.append(time_ddp(procs, threads, batch, repeats=args.repeats))
        else:
            rows += [time_setting(threads, batch, repeats=args.repeats, compile_model=c)
                     for c in ([False, True] if args.compile else [False])]
    for r in rows:
        print(f"{label(r):>14}: {r['s_per_step']:.3f} s/step, {r['steps_per_s']:.2f} steps/s, "
              f"{r['points_per_s']:,.0f} points/s (first step {r['first_step_s']:.1f} s)")
    base = rows[0]["points_per_s"]
    for r in rows[1:]:
        print(f"  {label(r)}: {r['points_per_s'] / base:.2f}x the points/s of {label(rows[0])}")
    if args.data:
        for batch in sorted({r["batch"] for r in rows}):
            print(f"sample_batch (batch {batch}): {time_sampling(args.data, batch, args.repeats):.3f} s")


if __name__ == "__main__":
    main()
