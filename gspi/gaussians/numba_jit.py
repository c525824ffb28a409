"""Numba settings shared by the compiled CPU rasterizer: on-disk cache and threads.

Cache (``cache=True``): numba stores compiled kernels next to the source, in
``gspi/gaussians/__pycache__`` (git-ignored, so a fresh clone fills it on the
first call); for a read-only install it falls back by itself to the user-wide
cache (``~/.cache/numba``), and ``NUMBA_CACHE_DIR`` overrides both. Where none of
these is writable numba refuses ``cache=True`` at decoration time; then
:func:`njit_cached` points ``numba.config.CACHE_DIR`` at a per-user folder in the
temp directory instead of failing the import.

Threads: the kernels run ``prange`` over tiles with :func:`threads` workers,
torch's thread count capped by ``NUMBA_NUM_THREADS``, so the one knob the CLIs
set (``threads=``, ``torch.set_num_threads``) governs both (:func:`set_threads`
pins another count, e.g. for the benchmark). Threading layer:
``workqueue`` unless ``NUMBA_THREADING_LAYER`` says otherwise. Numba's default
picks its OpenMP layer, a second libgomp beside torch's whose idle workers spin:
on the 2-core VM every torch op after a parallel region ran ~4x slower (a full
5k-surfel fwd+bwd took 110-160 ms instead of 29 ms). workqueue's workers sleep;
it must not be entered from two Python threads at once (gspi renders from one).
"""

from __future__ import annotations

import os
import tempfile

import numba
import torch

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"  # read when the first parallel kernel starts the pool


def fallback_cache_dir() -> str:
    """Per-user cache folder under the temp directory (used when nothing else is writable)."""
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return os.path.join(tempfile.gettempdir(), f"gspi-numba-cache-{uid}")


def njit_cached(**options):
    """``numba.njit(cache=True, error_model="numpy", **options)`` that survives an unwritable
    source tree and home. (The numpy error model drops the zero-division checks that the
    python model puts before every division; the kernels never divide by zero.)"""
    options = {"error_model": "numpy", **options}

    def wrap(fn):
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError as err:
            if "no locator available" not in str(err):
                raise
            numba.config.CACHE_DIR = fallback_cache_dir()
            return numba.njit(cache=True, **options)(fn)

    return wrap


_THREADS: list[int | None] = [None]  # set_threads override; None = follow torch


def set_threads(n: int | None) -> None:
    """Pins the kernels' worker count (e.g. numba 2 threads beside torch 1); None follows torch."""
    if n is not None and n < 1:
        raise ValueError(f"threads must be >= 1 or None, got {n}")
    _THREADS[0] = n


def threads() -> int:
    """Workers for a parallel kernel: :func:`set_threads`' value or torch's thread count,
    at most NUMBA_NUM_THREADS."""
    wanted = torch.get_num_threads() if _THREADS[0] is None else _THREADS[0]
    return max(1, min(wanted, numba.config.NUMBA_NUM_THREADS))
