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


def assert_cpu_pipelines_call(monkeypatch, owner, what: str) -> None:
    """Stage 0 (recon.render), lattice renders (Stage I), Stage III and relighting, each at their
    default backend on the CPU, reach ``owner.apply`` (a torch autograd Function)."""
    from gspi.gaussians.lattice_render import lattice_camera_tensors, render_lattice_views
    from gspi.gaussians.model import Gaussians2D
    from gspi.recon.render import render_views
    from gspi.relight import shade_asset
    from gspi.stage3.render import render_geometry, render_materials

    calls = []
    apply = owner.apply
    monkeypatch.setattr(owner, "apply", lambda *a: calls.append(1) or apply(*a))
    g = Gaussians2D.empty(30, 3, pbr=True)
    with torch.no_grad():
        g.means.copy_(torch.randn(30, 3, generator=torch.Generator().manual_seed(0)) * 0.3)
    vm, K = lattice_camera_tensors(16)
    vm, K = vm[:1], K[:1]
    entry_points = {
        "recon.render_views": lambda: render_views(g.means, g.quats, g.scales, g.opacities, g.sh, 3, vm, K, 16, 16),
        "render_lattice_views": lambda: render_lattice_views(g, image_size=16, lattice={"num_views": 1}),
        "stage3.render_geometry": lambda: render_geometry(g, vm, K, 16, 16),
        "stage3.render_materials": lambda: render_materials(g, vm, K, 16, 16),
        "relight.shade_asset": lambda: shade_asset(g, torch.ones(8, 16, 3), vm, K, 16, 16),
    }
    for name, call in entry_points.items():
        calls.clear()
        call()
        assert calls, f"{name} did not use {what}"
