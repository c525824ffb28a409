"""Speed of the evaluation protocol's pieces at 128 and 512 px (medians, machine named), and of
the commands a user waits for.

    python -m benchmarks.bench_eval
    python -m benchmarks.bench_eval --commands-only --gt demo_out/data \
        --pred "demo_out/runs/method=light_fit/predictions" --runs demo_out/runs

``--gt DATA --pred PRED``: wall seconds of ``gspi-eval gt=DATA pred=PRED out=<temp>``; ``--runs
RUNS``: of ``gspi-report RUNS out=<temp>``; each run as a subprocess (start-up and imports
included), ``--repeats`` times, alternating, every time printed.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from benchmarks.common import command_seconds, machine, median_seconds
from eval.lpips.net import load_lpips
from eval.metrics import masked_lpips, masked_psnr, masked_ssim
from eval.relight import clear_prefilter_cache, prefilter_environment, split_sum


def time_commands(gt: Path | None, pred: Path | None, runs: Path | None, repeats: int) -> None:
    commands = []
    if gt is not None and pred is not None:
        commands.append(("gspi-eval", lambda out: [f"gt={gt}", f"pred={pred}", f"out={out}"]))
    if runs is not None:
        commands.append(("gspi-report", lambda out: [str(runs), f"out={out}"]))
    times = {name: [] for name, _ in commands}
    for _ in range(repeats):
        for name, args in commands:
            with tempfile.TemporaryDirectory() as out:
                times[name].append(command_seconds(name, args(Path(out) / "out")))
    for name, ts in times.items():
        print(f"{name}: " + ", ".join(f"{t:.1f}" for t in ts) + f" s wall ({len(ts)} run(s))")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gt", type=Path, help="GT dataset for the gspi-eval command")
    ap.add_argument("--pred", type=Path, help="predictions for the gspi-eval command")
    ap.add_argument("--runs", type=Path, help="runs folder for the gspi-report command")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--commands-only", action="store_true", help="skip the protocol's pieces")
    args = ap.parse_args()
    print(f"machine: {machine()}")
    time_commands(args.gt, args.pred, args.runs, args.repeats)
    if args.commands_only:
        return
    g = torch.Generator().manual_seed(0)
    net = load_lpips()
    for size in (128, 512):
        pred, gt = torch.rand(size, size, 3, generator=g), torch.rand(size, size, 3, generator=g)
        mask = torch.zeros(size, size, dtype=torch.bool)
        mask[size // 8:-size // 8, size // 8:-size // 8] = True
        for name, fn in (("psnr", lambda: masked_psnr(pred, gt, mask)),
                         ("ssim", lambda: masked_ssim(pred, gt, mask)),
                         ("lpips", lambda: masked_lpips(pred, gt, mask, net=net))):
            print(f"{size:4d} px  {name:<6} {1000 * median_seconds(fn):8.1f} ms (median of 5)")
        n = torch.nn.functional.normalize(torch.randn(size, size, 3, generator=g), dim=-1)
        env = torch.rand(size // 2, size, 3, generator=g) * 4
        pre = prefilter_environment(env)
        args = (pred, pred[..., :1], pred[..., 1:2], n, n)
        t = median_seconds(lambda: split_sum(*args, pre))
        print(f"{size:4d} px  split_sum {1000 * t:8.1f} ms for {size}x{size} pixels")

    for h in (128, 256):
        env = torch.rand(h, 2 * h, 3, generator=g) * 4

        def prefilter():
            clear_prefilter_cache()
            prefilter_environment(env)
        print(f"prefilter {h}x{2 * h} env: {median_seconds(prefilter, repeats=3):.2f} s (median of 3)")


if __name__ == "__main__":
    main()
