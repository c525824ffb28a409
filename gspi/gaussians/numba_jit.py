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
set (``threads=``, ``torch.set_num_threads``) governs both.
"""

from __future__ import annotations

import os
import tempfile

import numba
import torch


def fallback_cache_dir() -> str:
    """Per-user cache folder under the temp directory (used when nothing else is writable)."""
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return os.path.join(tempfile.gettempdir(), f"gspi-numba-cache-{uid}")


def njit_cached(**options):
    """``numba.njit(cache=True, **options)`` that survives an unwritable source tree and home."""

    def wrap(fn):
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError as err:
            if "no locator available" not in str(err):
                raise
            numba.config.CACHE_DIR = fallback_cache_dir()
            return numba.njit(cache=True, **options)(fn)

    return wrap


def threads() -> int:
    """Workers for a parallel kernel: torch's thread count, at most NUMBA_NUM_THREADS."""
    return max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
