"""Shapes, sphere tracing, materials, patterns and environments of the procedural benchmark."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from eval.relight import irradiance_map
from eval.views import pixel_rays
from gspi.data.procedural import patterns
from gspi.data.environments import CAPTURE_ENVS, HELDOUT_ENVS, env_names, make_environment
from gspi.data.lattice import lattice_cameras
from gspi.data.procedural.materials import MATERIAL_CLASSES, evaluate_material, sample_material
from gspi.data.procedural.scene_recipe import assign_splits
from gspi.data.procedural.sdf_shapes import FAMILIES, ShapeSDF, sample_shape
from gspi.data.procedural.sphere_trace import sdf_normals, sphere_trace


@pytest.mark.parametrize("family", FAMILIES)
def test_shape_fits_unit_sphere_and_traces_exactly(family):
    shape = ShapeSDF(sample_shape(family, np.random.default_rng(7)))
    K, w2c = lattice_cameras(width=24, height=24)
    hits = 0
    for k in (0, 9, 20, 31):
        d = pixel_rays(K[k], w2c[k], 24, 24).reshape(-1, 3)
        o = torch.as_tensor(np.linalg.inv(w2c[k])[:3, 3], dtype=torch.float32).expand_as(d)
        tr = sphere_trace(shape, o.contiguous(), d, step_factor=shape.step_factor)
        p, n = tr.position[tr.hit], tr.normal[tr.hit]
        hits += len(p)
        assert p.norm(dim=-1).max() <= 1.0
        assert shape(p).abs().max() < 1e-3
        torch.testing.assert_close(n.norm(dim=-1), torch.ones(len(n)), atol=1e-5, rtol=0)
        assert ((n * d[tr.hit]).sum(-1) < 0.05).all()  # normals face the camera
        eps = 1e-3  # autograd normal == central-difference gradient direction
        fd = torch.stack([(shape(p + eps * e) - shape(p - eps * e)) / (2 * eps)
                          for e in torch.eye(3)], dim=-1)
        cos = (torch.nn.functional.normalize(fd, dim=-1) * n).sum(-1)
        assert cos.median() > 0.999
    assert hits > 4 * 24 * 24 * 0.05


def test_sdf_normals_of_a_sphere():
    p = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1) * 0.5
    n = sdf_normals(lambda x: x.norm(dim=-1) - 0.5, p)
    torch.testing.assert_close(n, p / 0.5)


@pytest.mark.parametrize("cls", MATERIAL_CLASSES)
def test_material_ranges_and_spatial_variation(cls):
    q = torch.rand(20000, 3) * 2 - 1
    q = torch.nn.functional.normalize(q, dim=-1) * torch.rand(20000, 1) ** 0.3
    m = evaluate_material(sample_material(cls, np.random.default_rng(1)), q)
    for x in (m.albedo_linear, m.roughness, m.metallic):
        assert x.min() >= 0 and x.max() <= 1 and torch.isfinite(x).all()
    assert set(m.metallic.unique().tolist()) <= {0.0, 1.0}
    assert m.albedo_linear.std(dim=0).max() > 0.01  # patterns: not a constant colour
    if cls in ("metal", "painted_metal", "ceramic"):
        assert 0 < m.metallic.mean() < 1  # metallic regions next to dielectric ones


def test_patterns_are_deterministic():
    q = torch.rand(1000, 3) * 4
    for fn in (lambda: patterns.fbm(q, 3), lambda: patterns.voronoi(q, 3)[2],
               lambda: patterns.glyph_stripes(q / 4, 3)):
        assert torch.equal(fn(), fn())
    f1, f2, _ = patterns.voronoi(q, 3)
    assert (f1 <= f2).all()


def test_environment_sets_are_disjoint_and_large_enough():
    assert len(env_names("capture")) >= 8 and len(env_names("heldout")) >= 4
    assert not set(CAPTURE_ENVS) & set(HELDOUT_ENVS)
    for table in (CAPTURE_ENVS, HELDOUT_ENVS):
        for kind, params in table.values():
            if kind == "sky" and params["sun_ratio"] > 0:
                assert 1e3 <= params["sun_ratio"] <= 1e4


@pytest.mark.parametrize("name", ["sky_noon", "studio_rgb", "dusk"])
def test_environment_exposure(name):
    env = make_environment(name, 16)
    assert env.shape == (16, 32, 3) and env.min() >= 0 and torch.isfinite(env).all()
    peak = irradiance_map(env, height=16).mean(dim=-1).max()
    assert float(peak) == pytest.approx(math.pi, rel=1e-4)
    assert torch.equal(env, make_environment(name, 16))


def test_splits_are_a_seeded_partition():
    names = [f"s{i}" for i in range(10)]
    a = assign_splits(names, 0, num_train=6, num_val=1, num_test=3)
    assert sorted(sum(a.values(), [])) == sorted(names)
    assert a == assign_splits(names, 0, num_train=6, num_val=1, num_test=3)
    assert a != assign_splits(names, 1, num_train=6, num_val=1, num_test=3)
