"""Toy scenes for the light read-out's tests: points on a sphere, views around each normal, shaded
by the project's own split-sum shader (tests/test_light.py, tests/test_light_refine.py)."""
from __future__ import annotations

import torch

from eval.relight import split_sum
from gspi.light.observations import PointViews
from gspi.light.readout import ROUGHNESS_GRID
from gspi.light.shading import turn_directions

H = 32  # small maps keep the prefilter fast


def unit(x):
    return torch.nn.functional.normalize(torch.as_tensor(x, dtype=torch.float32), dim=-1)


def toy_views(num_points: int, views: int, seed: int = 0):
    """Normals on the upper sphere and ``views`` directions per point within 80 degrees of it."""
    g = torch.Generator().manual_seed(seed)
    normal = unit(torch.randn(num_points, 3, generator=g))
    point = torch.arange(num_points).repeat_interleave(views)
    n = normal[point]
    d = unit(n + 0.9 * unit(torch.randn(len(point), 3, generator=g)))
    d = torch.where((d * n).sum(-1, keepdim=True) > 0.15, d, n)
    return point, d, normal


def shade(albedo, rough, metal, normal, view_dir, env):
    return split_sum(albedo, rough[:, None], metal[:, None], normal, view_dir, env)


def toy_scene(p_env, num_points=300, views=8, seed=0, gain=1.0, rotation_deg=0.0):
    """Points whose materials lie on the grid, shaded by the shader itself."""
    g = torch.Generator().manual_seed(seed)
    point, view_dir, normal = toy_views(num_points, views, seed)
    rough = torch.as_tensor(ROUGHNESS_GRID)[torch.randint(len(ROUGHNESS_GRID), (num_points,), generator=g)]
    metal = torch.randint(2, (num_points,), generator=g).float()
    albedo = 0.1 + 0.8 * torch.rand(num_points, 3, generator=g)
    colour = gain * shade(albedo[point], rough[point], metal[point], turn_directions(normal[point], rotation_deg),
                          turn_directions(view_dir, rotation_deg), p_env)
    xyz = normal.clone()  # points on the unit sphere
    obs = PointViews(point=point, colour=colour, view_dir=view_dir, normal=normal, xyz=xyz)
    return obs, albedo, rough, metal
