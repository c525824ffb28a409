"""Out of GPU memory in Stage II sampling: halve the Write chunk and carry on (issue #16).

``write_chunk`` bounds the memory of the point-side Write attention/MLP; a cloud that does not
fit at the configured chunk is retried with half the chunk, down to ``MIN_CHUNK`` points, each
shrink logged. The result does not depend on the chunk (the Write is point-wise). CUDA's
``torch.cuda.OutOfMemoryError`` is what is caught; tests inject it on the CPU.
"""
from __future__ import annotations

import logging
from typing import Callable, Optional, TypeVar

import torch

log = logging.getLogger(__name__)
MIN_CHUNK = 256
T = TypeVar("T")


def run_with_chunk_halving(fn: Callable[[Optional[int]], T], write_chunk: Optional[int], num_points: int,
                           *, min_chunk: int = MIN_CHUNK) -> tuple[T, Optional[int]]:
    """``fn(chunk)``, retried with half the chunk after each out-of-memory error.

    Returns:
        (fn's result, the chunk that fitted). ``write_chunk=None`` (no chunking) first shrinks
        to half the cloud. Raises the last OutOfMemoryError once the chunk is below ``min_chunk``.
    """
    chunk = write_chunk
    while True:
        try:
            return fn(chunk), chunk
        except torch.cuda.OutOfMemoryError:
            current = num_points if chunk is None else min(int(chunk), num_points)
            smaller = current // 2
            if smaller < min_chunk:
                log.error("Stage II sampling: out of GPU memory at write_chunk=%s (floor %d)", chunk, min_chunk)
                raise
            log.warning("Stage II sampling: out of GPU memory at write_chunk=%s; retrying with %d",
                        chunk, smaller)
            if torch.cuda.is_available():
                torch.cuda.empty_cache()
            chunk = smaller
