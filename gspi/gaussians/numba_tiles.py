"""Compiled (numba) tile binning: the same lists as :func:`gspi.gaussians.tiles.bin_splats`.

``bin_splats`` (the torch reference) expands every (surfel, tile) pair and sorts them by the
key (tile, front-to-back rank): two argsorts over the pairs and a dozen [pairs] tensors, ~2.3
ms of a ~30 ms Stage III step at 5.6k surfels and 128 px, ~14 ms at 50k surfels. Here the
valid surfels are ranked front to back once (a stable argsort of their depths, as the
reference ranks them), then a counting sort by tile walks them in that order: each tile's
list comes out front to back with ties broken by index, i.e. the reference's lists exactly
(tests/test_numba_tiles.py), in two passes over the pairs.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from gspi.gaussians.numba_jit import njit_cached
from gspi.gaussians.tiles import TileBins


@njit_cached()
def _count_and_fill(lo, hi, ranked, tile_size, tiles_x, n_tiles):
    """(splat_ids, offsets) of the surfels ``ranked`` (front to back) over their tile spans."""
    offsets = np.zeros(n_tiles + 1, np.int64)
    for i in ranked:
        for ty in range(lo[i, 1] // tile_size, hi[i, 1] // tile_size + 1):
            for tx in range(lo[i, 0] // tile_size, hi[i, 0] // tile_size + 1):
                offsets[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        offsets[t + 1] += offsets[t]
    fill = offsets[:-1].copy()
    ids = np.empty(offsets[n_tiles], np.int64)
    for i in ranked:
        for ty in range(lo[i, 1] // tile_size, hi[i, 1] // tile_size + 1):
            for tx in range(lo[i, 0] // tile_size, hi[i, 0] // tile_size + 1):
                t = ty * tiles_x + tx
                ids[fill[t]] = i
                fill[t] += 1
    return ids, offsets


@torch.no_grad()
def bin_splats_numba(lo_px: Tensor, hi_px: Tensor, valid: Tensor, depths: Tensor, width: int, height: int,
                     tile_size: int) -> TileBins:
    """:func:`gspi.gaussians.tiles.bin_splats` (same arguments, same :class:`TileBins`) on CPU tensors."""
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    ids = torch.nonzero(valid).squeeze(1)
    ranked = ids[torch.argsort(depths[ids], stable=True)].numpy()
    splat_ids, offsets = _count_and_fill(lo_px.to(torch.int64).numpy(), hi_px.to(torch.int64).numpy(), ranked,
                                         int(tile_size), tiles_x, tiles_x * tiles_y)
    return TileBins(tile_size, tiles_x, tiles_y, torch.from_numpy(splat_ids), torch.from_numpy(offsets))
