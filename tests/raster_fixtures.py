"""Random 2D-Gaussian surfel scenes for the rasterizer tests (tests/test_rasterize.py and
tests/test_rasterize_numba.py): n surfels around z = 3 for a camera at the origin looking down +z
(identity view matrix), with surfel 0 behind it, surfel 1 sub-pixel and surfel 2 at the opacity
clamp.
"""
from __future__ import annotations

import torch

DT = torch.float64  # the rasterizer tests' default dtype


def random_scene(n: int, seed: int, dtype=DT, spread: float = 0.6):
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen, dtype=dtype) * spread + torch.tensor([0.0, 0.0, 3.0], dtype=dtype)
    means[0] = torch.tensor([0.1, 0.0, -1.0], dtype=dtype)  # behind the camera
    quats = torch.randn(n, 4, generator=gen, dtype=dtype)
    scales = torch.exp(torch.rand(n, 2, generator=gen, dtype=dtype) * 3.5 - 4.5)  # 0.011 .. 0.37
    scales[1] = torch.tensor([1e-4, 2e-4], dtype=dtype)  # sub-pixel: only the 2D filter shows
    opacities = torch.rand(n, generator=gen, dtype=dtype) * 0.95 + 0.04
    opacities[2] = 1.0  # hits the 0.999 clamp
    colors = torch.rand(n, 4, generator=gen, dtype=dtype)
    return means, quats, scales, opacities, colors
