"""Per-stage wall time, CPU time and peak memory (the `stages` block of meta.json and the log).

CPU time is the process's (``time.process_time``: every thread of it): on a machine shared with
other jobs it is what the stage cost, where the wall time also counts the others' share of the cores.

Peak memory is the peak resident set size of the process DURING the stage, sampled every
20 ms from /proc/self/statm by a background thread (``resource.ru_maxrss`` is a lifetime peak
and cannot be reset per stage); on CUDA also ``torch.cuda.max_memory_allocated`` after a
reset. Where /proc is missing (macOS), the lifetime ``ru_maxrss`` is reported instead.
"""
from __future__ import annotations

import logging
import os
import resource
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Iterator, Optional

import torch

log = logging.getLogger(__name__)
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def current_rss_bytes() -> Optional[int]:
    """Resident set size of this process, or None without /proc."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


def lifetime_peak_rss_bytes() -> int:
    """``ru_maxrss`` in bytes (KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)


class _PeakSampler(threading.Thread):
    def __init__(self, interval_s: float = 0.02):
        super().__init__(daemon=True)
        self.interval_s, self.peak = interval_s, current_rss_bytes() or 0
        self._stop_event = threading.Event()

    def run(self) -> None:
        while not self._stop_event.wait(self.interval_s):
            rss = current_rss_bytes()
            if rss is not None and rss > self.peak:
                self.peak = rss

    def stop(self) -> int:
        self._stop_event.set()
        self.join()
        rss = current_rss_bytes()
        return max(self.peak, rss or 0)


# Test hook: GSPI_KILL_AT="<tag>:<stage>" SIGKILLs the process when that stage starts, to show
# that a killed sweep loses nothing on rerun (tests/test_run_sweep.py). Unset: no effect.
KILL_ENV = "GSPI_KILL_AT"


class StageClock:
    """Collects ``{stage: {"seconds", "cpu_seconds", "peak_rss_mb"[, "peak_cuda_mb"]}}`` for one scene.

    ``tag`` names the job (its ablation) for the log and the kill hook.
    """

    def __init__(self, scene: str = "", tag: str = ""):
        self.scene, self.tag = scene, tag
        self.stages: dict[str, dict] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[dict]:
        if os.environ.get(KILL_ENV) == f"{self.tag}:{name}":
            os.kill(os.getpid(), signal.SIGKILL)
        info: dict = {}
        cuda = torch.cuda.is_available()
        if cuda:
            torch.cuda.reset_peak_memory_stats()
        sampler = _PeakSampler() if current_rss_bytes() is not None else None
        if sampler:
            sampler.start()
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            yield info
        finally:
            seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
            peak = sampler.stop() if sampler else lifetime_peak_rss_bytes()
            info.update(seconds=round(seconds, 3), cpu_seconds=round(cpu, 3), peak_rss_mb=round(peak / 2**20, 1))
            if cuda:
                info["peak_cuda_mb"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
            self.stages[name] = {**self.stages.get(name, {}), **info}
            log.info("%s %s: %.1f s, peak RSS %.0f MB", self.scene, name, seconds, info["peak_rss_mb"])

    def seconds(self, *names: str) -> float:
        """Total seconds of the named stages that ran."""
        return float(sum(self.stages[n]["seconds"] for n in names if n in self.stages))
