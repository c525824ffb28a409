"""Time per denoising step of the Stage II RCW denoiser at N = 1e3, 1e4, 1e5 points (one forward
pass, batch 1, 32 global-prior views, no grad), and the time ratios that show O(N) growth.

    python -m benchmarks.bench_stage2                # small CPU model
    python -m benchmarks.bench_stage2 --threads 1    # on a shared machine (no OpenMP spin-waits)
    python -m benchmarks.bench_stage2 --paper        # PointInfinity sizes (GPU advised)
"""
from __future__ import annotations

import argparse

import torch

from benchmarks.common import machine, median_seconds
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import RCWConfig, RCWDenoiser, count_parameters

# Small CPU model: the sizes of the research notes' CPU-test suggestion, doubled.
CPU_CONFIG = RCWConfig(num_latents=64, latent_dim=128, point_dim=64, num_blocks=2, num_compute_layers=2,
                       num_heads=4, global_token_dim=384)
POINT_COUNTS = (1_000, 10_000, 100_000)
NUM_VIEWS = 32
WRITE_CHUNK = 16_384


def make_inputs(num_points: int, config: RCWConfig, device: torch.device) -> tuple[torch.Tensor, Stage2Inputs]:
    g = torch.Generator().manual_seed(0)
    xyz = torch.nn.functional.normalize(torch.randn(1, num_points, 3, generator=g), dim=-1)
    local = torch.rand(1, num_points, config.local_cond_dim, generator=g)
    tokens = torch.randn(1, NUM_VIEWS, 25, config.global_token_dim, generator=g)
    f_t = torch.randn(1, num_points, 5, generator=g)
    inputs = Stage2Inputs(xyz=xyz, local_cond=local, global_tokens=tokens)
    return f_t.to(device), inputs.to(device)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper", action="store_true", help="PointInfinity sizes instead of the CPU model")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    config = RCWConfig() if args.paper else CPU_CONFIG
    torch.manual_seed(0)
    model = RCWDenoiser(config).eval().to(device)
    print(f"machine: {machine()}")
    print(f"model: {count_parameters(model) / 1e6:.2f} M parameters, {config}")
    print(f"latent tokens: {config.num_latent_tokens(NUM_VIEWS)} ({NUM_VIEWS} views), write_chunk {WRITE_CHUNK}")
    times = []
    for n in POINT_COUNTS:
        f_t, inputs = make_inputs(n, config, device)

        def step() -> None:
            with torch.no_grad():
                model(f_t, torch.tensor([500], device=device), inputs, write_chunk=WRITE_CHUNK)
            if device.type == "cuda":
                torch.cuda.synchronize()
        times.append(median_seconds(step, repeats=args.repeats))
        per_point = 1e6 * times[-1] / n
        print(f"N = {n:>7,d}: {1000 * times[-1]:9.1f} ms per step (median of {args.repeats}), {per_point:.2f} us/point")
    for (n0, t0), (n1, t1) in zip(zip(POINT_COUNTS, times), zip(POINT_COUNTS[1:], times[1:])):
        print(f"N x{n1 // n0} ({n0:,} -> {n1:,}): time x{t1 / t0:.2f}")


if __name__ == "__main__":
    main()
