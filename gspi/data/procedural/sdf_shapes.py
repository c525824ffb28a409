"""Implicit shapes (signed distance functions) of the procedural PBR benchmark.

Why SDFs: the benchmark needs *exact* per-pixel ground truth (depth, normals, material at the
surface point) without a mesh library or a rasteriser. An analytic SDF gives the surface point
by sphere tracing (`gspi.data.procedural.sphere_trace`), its normal as the exact gradient of the same
expression (torch autograd), and its object-space position for 3D procedural materials, all in
a few lines of dependency-free torch that batches every ray of a view and runs fast on 2 CPU
cores: `benchmarks/bench_data.py` measured 0.37-0.88 M rays/s per thread for the tracer alone
(128 px, 8 views batched, 2-core Xeon) and ~0.3 M rays/s end to end (materials, shading, files).

A shape is a JSON-serialisable *recipe* (stored in `scene.json`, key `generator.shape`), so the
exact surface can be rebuilt from the dataset (the point-cloud test does this):

    {"family": str, "params": {...}, "rotation": [3x3], "center": [3], "scale": float}

World point p -> local point q = R^T p (unit-bounding-sphere frame, used by the materials)
-> raw point x = center + scale * q -> sdf(p) = sdf_raw(x) / scale.
`center` and `scale` are fitted numerically so the object fits the unit sphere.

Families (7): sphere, torus, rounded_box, capsule, superquadric, blob (smooth union of spheres
with an optional sinusoidal displacement), multipart (a mug or a base-stem-top "totem").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

FAMILIES = ("sphere", "torus", "rounded_box", "capsule", "superquadric", "blob", "multipart")


# ---------------------------------------------------------------- primitives ([N, 3] -> [N])
def sd_sphere(x: Tensor, r: float) -> Tensor:
    return x.norm(dim=-1) - r


def sd_torus(x: Tensor, major: float, minor: float) -> Tensor:
    """Torus around the local z axis."""
    q = torch.stack([x[:, :2].norm(dim=-1) - major, x[:, 2]], dim=-1)
    return q.norm(dim=-1) - minor


def sd_round_box(x: Tensor, half: list[float], rounding: float) -> Tensor:
    q = x.abs() - torch.tensor(half, dtype=x.dtype, device=x.device) + rounding
    outside = q.clamp_min(0.0).norm(dim=-1)
    inside = q.max(dim=-1).values.clamp_max(0.0)
    return outside + inside - rounding


def sd_capsule(x: Tensor, a: list[float], b: list[float], r: float) -> Tensor:
    a_t, b_t = (torch.tensor(v, dtype=x.dtype, device=x.device) for v in (a, b))
    pa, ba = x - a_t, b_t - a_t
    h = ((pa @ ba) / (ba @ ba)).clamp(0.0, 1.0)
    return (pa - h[:, None] * ba).norm(dim=-1) - r


def sd_cylinder(x: Tensor, r: float, half_height: float, z0: float = 0.0) -> Tensor:
    """Capped cylinder along z, centred at height z0."""
    d = torch.stack([x[:, :2].norm(dim=-1) - r, (x[:, 2] - z0).abs() - half_height], dim=-1)
    return d.max(dim=-1).values.clamp_max(0.0) + d.clamp_min(0.0).norm(dim=-1)


def sd_superquadric(x: Tensor, axes: list[float], e1: float, e2: float) -> Tensor:
    """Barr superquadric, radially scaled inside-outside function (a distance *bound* only
    after the 0.5 step factor of the recipe; exponents keep the gradient finite)."""
    a = torch.tensor(axes, dtype=x.dtype, device=x.device)
    y = (x / a).abs() + 1e-12
    xy = (y[:, 0] ** (2.0 / e2) + y[:, 1] ** (2.0 / e2)) ** (e2 / e1)
    f = (xy + y[:, 2] ** (2.0 / e1)) ** (e1 / 2.0)
    return (f - 1.0) * float(min(axes))


def smooth_min(a: Tensor, b: Tensor, k: float) -> Tensor:
    """Polynomial smooth minimum (Quilez); k = blend radius, preserves the distance bound."""
    h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


# ------------------------------------------------------------------ raw SDF of a recipe
def _sd_blob(x: Tensor, p: dict) -> Tensor:
    d = None
    for c, r in zip(p["centers"], p["radii"]):
        s = sd_sphere(x - torch.tensor(c, dtype=x.dtype, device=x.device), r)
        d = s if d is None else smooth_min(d, s, p["blend"])
    if p["disp_amp"] > 0:
        f = p["disp_freq"]
        d = d + p["disp_amp"] * (torch.sin(f * x[:, 0]) * torch.sin(f * x[:, 1])
                                 * torch.sin(f * x[:, 2]))
    return d


def _sd_multipart(x: Tensor, p: dict) -> Tensor:
    if p["template"] == "mug":
        outer = sd_cylinder(x, p["radius"], p["half_height"])
        inner = sd_cylinder(x, p["radius"] - p["wall"], p["half_height"], z0=p["wall"])
        body = torch.maximum(outer, -inner)
        hx = x - torch.tensor([p["radius"], 0.0, 0.0], dtype=x.dtype, device=x.device)
        handle = sd_torus(hx[:, [0, 2, 1]], p["handle_major"], p["handle_minor"])  # xz-plane ring
        return torch.minimum(body, handle)
    base = sd_cylinder(x, p["base_radius"], p["base_half"], z0=-0.9)
    stem = sd_capsule(x, [0.0, 0.0, -0.9], [0.0, 0.0, p["stem_top"]], p["stem_radius"])
    t = x - torch.tensor([0.0, 0.0, p["stem_top"]], dtype=x.dtype, device=x.device)
    if p["top"] == "sphere":
        top = sd_sphere(t, p["top_size"])
    elif p["top"] == "torus":
        top = sd_torus(t, p["top_size"], 0.3 * p["top_size"])
    else:
        top = sd_round_box(t, [p["top_size"]] * 3, 0.25 * p["top_size"])
    return smooth_min(smooth_min(base, stem, 0.08), top, 0.08)


def raw_sdf(family: str, params: dict, x: Tensor) -> Tensor:
    """Signed distance (bound) of the un-normalised shape at raw points x [N, 3] -> [N]."""
    if family == "sphere":
        return sd_sphere(x, params["radius"])
    if family == "torus":
        return sd_torus(x, params["major"], params["minor"])
    if family == "rounded_box":
        return sd_round_box(x, params["half"], params["rounding"])
    if family == "capsule":
        return sd_capsule(x, params["a"], params["b"], params["radius"])
    if family == "superquadric":
        return sd_superquadric(x, params["axes"], params["e1"], params["e2"])
    if family == "blob":
        return _sd_blob(x, params)
    if family == "multipart":
        return _sd_multipart(x, params)
    raise ValueError(f"unknown shape family {family!r}; allowed: {', '.join(FAMILIES)}")


def step_factor(family: str, params: dict) -> float:
    """Safety factor (<= 1) on sphere-tracing steps for SDFs that are only distance bounds."""
    if family == "superquadric":
        return 0.5
    if family == "blob" and params["disp_amp"] > 0:
        return 1.0 / (1.0 + params["disp_amp"] * params["disp_freq"] * math.sqrt(3.0))
    return 1.0


# ------------------------------------------------------------------ sampling by seed
def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def sample_params(family: str, rng: np.random.Generator) -> dict:
    """Random raw parameters of a family (raw units ~1; normalised afterwards)."""
    if family == "sphere":
        return {"radius": 1.0}
    if family == "torus":
        return {"major": 1.0, "minor": _u(rng, 0.25, 0.5)}
    if family == "rounded_box":
        return {"half": [_u(rng, 0.5, 1.0), _u(rng, 0.5, 1.0), _u(rng, 0.4, 1.0)],
                "rounding": _u(rng, 0.05, 0.3)}
    if family == "capsule":
        h = _u(rng, 0.4, 0.9)
        return {"a": [0.0, 0.0, -h], "b": [0.0, 0.0, h], "radius": _u(rng, 0.3, 0.55)}
    if family == "superquadric":
        return {"axes": [_u(rng, 0.6, 1.0), _u(rng, 0.6, 1.0), _u(rng, 0.5, 1.0)],
                "e1": _u(rng, 0.3, 1.6), "e2": _u(rng, 0.3, 1.6)}
    if family == "blob":
        n = int(rng.integers(3, 6))
        centers = [[_u(rng, -0.6, 0.6) for _ in range(3)] for _ in range(n)]
        radii = [_u(rng, 0.3, 0.6) for _ in range(n)]
        displaced = bool(rng.uniform() < 0.5)
        return {"centers": centers, "radii": radii, "blend": _u(rng, 0.15, 0.35),
                "disp_amp": _u(rng, 0.02, 0.05) if displaced else 0.0,
                "disp_freq": _u(rng, 6.0, 12.0)}
    if family == "multipart":
        if rng.uniform() < 0.5:
            return {"template": "mug", "radius": _u(rng, 0.5, 0.7),
                    "half_height": _u(rng, 0.5, 0.8),
                    "wall": _u(rng, 0.06, 0.1), "handle_major": _u(rng, 0.25, 0.35),
                    "handle_minor": _u(rng, 0.05, 0.08)}
        return {"template": "totem", "base_radius": _u(rng, 0.5, 0.8),
                "base_half": _u(rng, 0.08, 0.15),
                "stem_radius": _u(rng, 0.08, 0.15), "stem_top": _u(rng, 0.2, 0.5),
                "top": ["sphere", "torus", "box"][int(rng.integers(0, 3))],
                "top_size": _u(rng, 0.3, 0.45)}
    raise ValueError(f"unknown shape family {family!r}; allowed: {', '.join(FAMILIES)}")


def random_rotation(rng: np.random.Generator, *, max_tilt_deg: float | None) -> np.ndarray:
    """[3, 3] rotation: uniform (None) or a tilt up to `max_tilt_deg` times a random azimuth."""
    if max_tilt_deg is None:
        q = rng.normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    az, tilt, tilt_dir = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(0, max_tilt_deg)), \
        rng.uniform(0, 2 * np.pi)
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    axis = np.array([np.cos(tilt_dir), np.sin(tilt_dir), 0.0])
    kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rt = np.eye(3) + np.sin(tilt) * kx + (1 - np.cos(tilt)) * kx @ kx
    return rt @ rz


def fit_unit_sphere(family: str, params: dict, *, grid: int = 48, bound: float = 2.5,
                    fit_radius: float = 0.97) -> tuple[list[float], float]:
    """Centre and scale that put the raw shape inside a sphere of radius `fit_radius`.

    Evaluates the raw SDF on a grid^3 lattice over [-bound, bound]^3, projects the grid points
    within one voxel of the surface onto it (Newton steps x -= f grad f / |grad f|^2, float64),
    and takes the bounding-box centre and the farthest projected point of that surface sample.

    Returns:
        (center [3], scale): raw point = center + scale * unit-sphere point.
    """
    ax = torch.linspace(-bound, bound, grid, dtype=torch.float64)
    x = torch.stack(torch.meshgrid(ax, ax, ax, indexing="ij"), dim=-1).reshape(-1, 3)
    voxel_diag = math.sqrt(3.0) * (2 * bound / (grid - 1))
    near = x[raw_sdf(family, params, x).abs() < voxel_diag]
    if len(near) == 0:
        raise ValueError(f"fit_unit_sphere: {family} shape has no surface on the grid: {params}")
    for _ in range(12):
        p = near.clone().requires_grad_(True)
        f = raw_sdf(family, params, p)
        (g,) = torch.autograd.grad(f.sum(), p)
        near = (p - (f / (g * g).sum(-1).clamp_min(1e-12))[:, None] * g).detach()
    center = 0.5 * (near.min(dim=0).values + near.max(dim=0).values)
    radius = float((near - center).norm(dim=-1).max())
    return [float(c) for c in center], radius / fit_radius


def sample_shape(family: str, rng: np.random.Generator) -> dict:
    """A complete, JSON-serialisable shape recipe (see module docstring)."""
    params = sample_params(family, rng)
    tilt = 25.0 if family == "multipart" else None
    rotation = random_rotation(rng, max_tilt_deg=tilt)
    center, scale = fit_unit_sphere(family, params)
    return {"family": family, "params": params, "rotation": rotation.tolist(),
            "center": center, "scale": scale}


@dataclass
class ShapeSDF:
    """A normalised shape in the world frame, built from a recipe (fits the unit sphere)."""

    recipe: dict

    def __post_init__(self) -> None:
        self.family = self.recipe["family"]
        self.params = self.recipe["params"]
        self.rotation = torch.tensor(self.recipe["rotation"], dtype=torch.float32)  # local->world
        self.center = torch.tensor(self.recipe["center"], dtype=torch.float32)
        self.scale = float(self.recipe["scale"])
        self.step_factor = step_factor(self.family, self.params)

    def local(self, p_world: Tensor) -> Tensor:
        """[N, 3] world -> [N, 3] object frame (unit-sphere scale; materials live here)."""
        return p_world @ self.rotation.to(p_world.device)

    def __call__(self, p_world: Tensor) -> Tensor:
        """[N, 3] world points -> [N] signed distance bound (world units), on their device."""
        x = self.center.to(p_world.device) + self.scale * self.local(p_world)
        return raw_sdf(self.family, self.params, x) / self.scale
