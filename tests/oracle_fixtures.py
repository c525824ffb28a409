"""Inputs shared by the oracle goldens' recorder (tests/golden/record_oracles.py) and their tests.

Both sides build the same tensors from these functions, so a golden is the reference package's
answer to exactly the input the test gives our code.
"""
from __future__ import annotations

import hashlib

import torch

from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import DenoiserOutput

NUM_STEPS_CASES = (1, 10, 30, 50, 999)
# key -> (clip_sample, use_clipped_model_output, eta)
FULL_LOOP_CASES = {"clip": (True, False, 0.0), "noclip": (False, False, 0.0),
                   "clip_use_clipped": (True, True, 0.0), "clip_eta1": (True, False, 1.0)}
SPATIAL_STRIDE = 8  # LPIPS spatial maps are stored as row/column sums plus every 8th pixel


def make_f0(b=2, n=16, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(b, n, 5, generator=g, dtype=torch.float64) * 1.8 - 0.9  # inside [-1, 1]


def make_inputs(f0):
    b, n = f0.shape[:2]
    return Stage2Inputs(xyz=torch.zeros(b, n, 3, dtype=f0.dtype), local_cond=torch.zeros(b, n, 35, dtype=f0.dtype))


class AffineEpsModel(torch.nn.Module):
    """A smooth eps(f_t, t) with no fixed point at the data, for comparing sampler loops."""

    def forward(self, f_t, t, inputs, *, prev_latents=None, cond_keep=None, write_chunk=None):
        scale = 0.9 if cond_keep is None else 0.7
        return DenoiserOutput(eps=scale * f_t + 0.3 * torch.sin(f_t + t[0] / 100.0), latents=f_t[:, :1])


def add_noise_inputs():
    """(f0 [2, 16, 5] float32, eps [2, 16, 5], t [2]) for q_sample vs DDIMScheduler.add_noise."""
    f0 = make_f0().float()
    eps = torch.randn(f0.shape, generator=torch.Generator().manual_seed(3))
    return f0, eps, torch.tensor([0, 999])


def full_loop_noise(f0):
    """(generator, initial sample): the generator goes on to draw the eta > 0 noise."""
    g = torch.Generator().manual_seed(11)
    return g, torch.randn(f0.shape, generator=g)


def lpips_inputs():
    """Two batches [4, 3, 96, 128] in [-1, 1]."""
    g = torch.Generator().manual_seed(1)
    return tuple(torch.rand(4, 3, 96, 128, generator=g) * 2 - 1 for _ in range(2))


def summarize_spatial(smap: torch.Tensor) -> dict:
    """A [B, 1, H, W] LPIPS map as per-image row sums, column sums and a strided sample."""
    m = smap[:, 0].double()
    return {"row_sums": m.sum(2).tolist(), "col_sums": m.sum(1).tolist(),
            "strided": m[:, ::SPATIAL_STRIDE, ::SPATIAL_STRIDE].tolist()}


def state_dict_sha256(state_dict: dict) -> str:
    """SHA-256 of a state dict's float32 tensor bytes in key order (``lins.*`` aliases of lpips skipped)."""
    h = hashlib.sha256()
    for key in sorted(k for k in state_dict if not k.startswith("lins.")):
        h.update(key.encode())
        h.update(state_dict[key].detach().float().contiguous().numpy().tobytes())
    return h.hexdigest()
