"""Timing helpers for benchmarks: medians over repeats, console scripts run and timed, and the
machine named in the output."""
from __future__ import annotations

import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]


def machine() -> str:
    cpu = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    gpu = f", GPU {torch.cuda.get_device_name()}" if torch.cuda.is_available() else ""
    return (f"{platform.node()}: {cpu}, {os.cpu_count()} cores, torch {torch.__version__}, "
            f"{torch.get_num_threads()} threads{gpu}")


def median_seconds(fn, *, repeats: int = 5, warmup: int = 1) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def command_seconds(name: str, args: list[str], *, env: dict | None = None, cwd: Path | None = None) -> float:
    """Wall seconds of the console script ``name`` installed beside this Python, run with ``args``
    (one torch thread, this checkout first on the path, ``env`` added); a failure stops the
    benchmark with the command and the tail of its stderr."""
    script = shutil.which(name, path=str(Path(sys.executable).parent))
    if script is None:
        raise SystemExit(f"{name}: not installed beside {sys.executable} (make install)")
    full_env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", **(env or {})}
    start = time.perf_counter()
    done = subprocess.run([script, *args], env=full_env, cwd=cwd, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{name} {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return seconds
