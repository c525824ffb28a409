"""Patch-wise Stage II inference (issue 52): the cloud as overlapping k-NN patches of the
training items' size, sampled as one batch and blended.

Training reads local subsets of ``stage2.data.num_points`` (512) points: a centre and its
nearest neighbours, in the frame of the whole scene (``gspi.stage2.data``). The paper samples
the whole cloud at once through the same 32 latents, so a model whose per-part decision was
learnt on patches has to keep it through a whole-object bottleneck; at CPU scale it paints one
material over the object. ``stage2.inference.patch_points`` (a named departure, off = the
paper) samples what training saw instead:

* **cover**: centres by farthest-point sampling (seeded start), ``ceil(coverage * N / n)`` of
  them, each patch its centre's n nearest neighbours; a point no patch holds gets its own patch
  centred on it, so every point is covered.
* **sample**: every patch is one batch item with the same coordinates frame, conditions and
  global prior as the whole cloud; f_T is drawn per patch from the run's generator.
* **blend**: a point in several patches takes their weighted mean, weight
  ``exp(-2 (d / r)^2)`` with d its distance to the patch centre and r the patch radius, so a
  patch's border, where its context is cut, counts least. A point in one patch takes that
  patch's value as is: a single patch holding the whole cloud equals whole-cloud inference.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor


def farthest_point_centres(xyz: np.ndarray, count: int, seed: int) -> np.ndarray:
    """[count] indices of ``xyz`` [N, 3] by farthest-point sampling from a seeded first point."""
    count = min(count, len(xyz))
    centres = np.empty(count, dtype=np.int64)
    centres[0] = np.random.default_rng(seed).integers(len(xyz))
    dist = np.linalg.norm(xyz - xyz[centres[0]], axis=1)
    for i in range(1, count):
        centres[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(xyz - xyz[centres[i]], axis=1))
    return centres


def cover_patches(xyz: np.ndarray, patch_points: int, *, coverage: float = 2.0, seed: int = 0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(patches [B, n] sorted point indices, centres [B]) that together hold every point of xyz [N, 3]."""
    if patch_points <= 0 or coverage <= 0:
        raise ValueError(f"stage2.inference.patch_points ({patch_points}) and patch_coverage ({coverage}) "
                         "must be positive")
    n_total = len(xyz)
    if patch_points >= n_total:
        return np.arange(n_total)[None], np.zeros(1, dtype=np.int64)
    tree = cKDTree(xyz)
    centres = list(farthest_point_centres(xyz, math.ceil(coverage * n_total / patch_points), seed))
    _, idx = tree.query(xyz[centres], k=patch_points)
    patches = [np.sort(row) for row in np.asarray(idx, dtype=np.int64)]
    covered = np.zeros(n_total, dtype=bool)
    for row in patches:
        covered[row] = True
    while not covered.all():  # rare: a stray point no centre's neighbourhood reached
        centre = int(np.flatnonzero(~covered)[0])
        _, row = tree.query(xyz[centre], k=patch_points)
        patches.append(np.sort(np.asarray(row, dtype=np.int64)))
        centres.append(centre)
        covered[patches[-1]] = True
    return np.stack(patches), np.asarray(centres, dtype=np.int64)


def blend_weights(xyz: np.ndarray, patches: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """[B, n] ``exp(-2 (d / r)^2)``: d = distance to the patch's centre, r = the patch's radius."""
    d = np.linalg.norm(xyz[patches] - xyz[centres][:, None], axis=-1)
    radius = np.maximum(d.max(axis=1, keepdims=True), 1e-12)
    return np.exp(-2.0 * (d / radius) ** 2)


def blend_patches(values: Tensor, patches: np.ndarray, weights: np.ndarray, num_points: int) -> Tensor:
    """[N, C]: per point the weighted mean of the patch values [B, n, C] that hold it; a point in
    one patch takes its value unchanged (no rounding)."""
    flat_idx = torch.from_numpy(patches.reshape(-1))
    flat_val = values.reshape(-1, values.shape[-1]).double()
    w = torch.from_numpy(weights.reshape(-1, 1)).double()
    total = torch.zeros(num_points, values.shape[-1], dtype=torch.float64).index_add_(0, flat_idx, flat_val * w)
    weight = torch.zeros(num_points, 1, dtype=torch.float64).index_add_(0, flat_idx, w)
    count = torch.bincount(flat_idx, minlength=num_points)
    out = (total / weight).to(values.dtype)
    single = count == 1
    if single.any():
        last = torch.zeros(num_points, dtype=torch.long)
        last[flat_idx] = torch.arange(len(flat_idx))  # the one slot of each singly-covered point
        out[single] = values.reshape(-1, values.shape[-1])[last[single]]
    return out


def patch_batches(patches: np.ndarray, batch: Optional[int]) -> list[slice]:
    """Slices of the patch list, ``batch`` patches each (None: all at once)."""
    step = len(patches) if not batch else max(1, int(batch))
    return [slice(s, s + step) for s in range(0, len(patches), step)]
