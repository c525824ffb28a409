"""Tests of the split-sum IBL shader (eval.envmap, eval.brdf_lut, eval.relight)."""

from __future__ import annotations

import math

import pytest
import torch

from eval import relight
from eval.brdf_lut import _dfg_rows, dfg_lut, hammersley, lookup_dfg
from eval.envmap import (downsample_latlong, latlong_directions, latlong_solid_angles,
                         sample_latlong, zonal_filter)
from eval.relight import (ggx_prefilter, irradiance_map,
                          prefilter_environment, split_sum)

F64 = torch.float64


def _unit(v):
    return torch.nn.functional.normalize(torch.as_tensor(v, dtype=torch.float32), dim=-1)


def _specular_albedo_mc(roughness, n_dot_v, n=600, seed=0):
    """Independent estimate of int f_spec(l, v) (n.l) dl, stratified UNIFORM hemisphere.

    Returns ``(I0, I1)``, the integrals for F0 = 0 and F0 = 1; by linearity of Schlick
    Fresnel the value for any F0 is ``I0 + F0 (I1 - I0)``.

    GGX D, height-correlated Smith, Schlick Fresnel, alpha = roughness^2; jittered
    strata in (cos theta, phi) -- no importance sampling, no LUT code.
    """
    g = torch.Generator().manual_seed(seed)
    a2 = roughness ** 4
    i = torch.arange(n, dtype=F64)[:, None]
    j = torch.arange(2 * n, dtype=F64)[None, :]
    mu = (i + torch.rand(n, 2 * n, generator=g, dtype=F64)) / n
    ph = (j + torch.rand(n, 2 * n, generator=g, dtype=F64)) / (2 * n) * 2 * math.pi
    s = torch.sqrt(1 - mu * mu)
    l_dir = torch.stack([s * torch.cos(ph), s * torch.sin(ph), mu], -1)
    v = torch.tensor([math.sqrt(1 - n_dot_v ** 2), 0.0, n_dot_v], dtype=F64)
    h = torch.nn.functional.normalize(l_dir + v, dim=-1)
    noh, voh, nol = h[..., 2], (h * v).sum(-1), mu
    d = a2 / (math.pi * ((a2 - 1) * noh * noh + 1) ** 2)
    vis = 0.5 / (nol * math.sqrt(n_dot_v ** 2 * (1 - a2) + a2)
                 + n_dot_v * torch.sqrt(nol * nol * (1 - a2) + a2))
    base = d * vis * nol * 2 * math.pi
    return float((base * (1 - voh) ** 5).mean()), float(base.mean())


def _structured_env(h=128, w=256):
    d = latlong_directions(h, w)
    blob = torch.exp(30 * (d @ _unit([0.4, -0.6, 0.7]) - 1))
    return (0.5 + 0.4 * d[..., :1] + 0.3 * d[..., 1:2] + 0.2 * d[..., 2:]
            + blob[..., None] * torch.tensor([2.0, 1.5, 1.0]))


# ---------------------------------------------------------------- envmap convention

def test_latlong_directions_convention():
    h, w = 64, 128
    d = latlong_directions(h, w)
    assert d.shape == (h, w, 3)
    assert torch.allclose(d.norm(dim=-1), torch.ones(h, w), atol=1e-6)
    assert (d[0, :, 2] > math.cos(math.pi / h)).all()  # top row next to +z
    assert (d[-1, :, 2] < -math.cos(math.pi / h)).all()
    eq = d[h // 2 - 1] + d[h // 2]  # symmetric about the equator
    mid = _unit(eq[w // 2 - 1] + eq[w // 2])  # centre column boundary: azimuth 0
    assert torch.allclose(mid, torch.tensor([1.0, 0, 0]), atol=1e-6)
    quarter = _unit(eq[w // 4 - 1] + eq[w // 4])  # azimuth +pi/2
    assert torch.allclose(quarter, torch.tensor([0, 1.0, 0]), atol=1e-6)
    theta = torch.atan2(d[h // 3, :, 1], d[h // 3, :, 0])
    expect = torch.remainder(math.pi - (torch.arange(w) + 0.5) * 2 * math.pi / w + math.pi,
                             2 * math.pi) - math.pi
    assert torch.allclose(theta, expect, atol=1e-5)


def test_solid_angles_sum_to_4pi():
    for h, w in [(16, 32), (100, 200), (7, 5)]:
        sa = latlong_solid_angles(h, w, dtype=F64)
        assert sa.shape == (h, 1) and (sa > 0).all()
        assert abs(float(sa.sum()) * w - 4 * math.pi) < 1e-12


def test_sample_latlong_roundtrip_and_wrap():
    env = torch.rand(24, 48, 3, generator=torch.Generator().manual_seed(1))
    d = latlong_directions(24, 48)
    assert torch.allclose(sample_latlong(env, d), env, atol=1e-5)
    got = sample_latlong(env, d[None, :3, :5].expand(2, 3, 5, 3))  # any leading shape
    assert got.shape == (2, 3, 5, 3)
    row = 10  # azimuth +pi (left edge) averages the first and last columns
    phi = math.pi / 2 - (row + 0.5) * math.pi / 24
    edge = torch.tensor([[-math.cos(phi), 0.0, math.sin(phi)]])
    assert torch.allclose(sample_latlong(env, edge)[0], 0.5 * (env[row, 0] + env[row, -1]),
                          atol=1e-5)
    pole = sample_latlong(env, torch.tensor([[0.0, 0.0, 1.0]]))[0]  # clamped to row 0
    assert torch.isfinite(pole).all() and pole.min() >= env[0].min() - 1e-6


def test_downsample_preserves_integral():
    env = torch.rand(32, 64, 3, generator=torch.Generator().manual_seed(2), dtype=F64)
    small = downsample_latlong(env, 4)
    assert small.shape == (8, 16, 3)
    integral = lambda e: (e * latlong_solid_angles(*e.shape[:2], dtype=F64)[..., None]).sum((0, 1))
    assert torch.allclose(integral(small), integral(env), rtol=1e-10)
    with pytest.raises(ValueError):
        downsample_latlong(env, 3)


def _brute_force(env, weight_fn):
    """Explicit double sum over all texel pairs (float64)."""
    h, w, _ = env.shape
    d = latlong_directions(h, w, dtype=F64).reshape(-1, 3)
    sa = latlong_solid_angles(h, w, dtype=F64).expand(h, w).reshape(-1)
    wts = weight_fn(d[:, None, :], d[None, :, :]) * sa[None, :]  # [out, in]
    return ((wts @ env.reshape(-1, 3).to(F64)) / wts.sum(1, keepdim=True)).reshape(h, w, 3)


def test_ggx_prefilter_matches_explicit_double_sum():
    env = torch.rand(8, 16, 3, generator=torch.Generator().manual_seed(3)) ** 3 * 4
    for rough in (0.3, 0.7):
        a2 = rough ** 4

        def weight(r, wi):
            hv = torch.nn.functional.normalize(r + wi, dim=-1)
            noh = (hv * r).sum(-1)  # N = R
            dggx = a2 / (math.pi * ((a2 - 1) * noh ** 2 + 1) ** 2)
            return dggx * (r * wi).sum(-1).clamp_min(0)

        ref = _brute_force(env, weight)
        assert torch.allclose(ggx_prefilter(env, rough).to(F64), ref, rtol=1e-4, atol=1e-5)


def test_irradiance_matches_explicit_double_sum():
    env = torch.rand(8, 16, 3, generator=torch.Generator().manual_seed(4))
    ref = math.pi * _brute_force(env, lambda n, wi: (n * wi).sum(-1).clamp_min(0))
    got = math.pi * zonal_filter(env, lambda c: c.clamp_min(0))
    assert torch.allclose(got.to(F64), ref, rtol=1e-5, atol=1e-5)


# ---------------------------------------------------------------- prefiltering

def test_irradiance_analytic():
    h, w = 128, 256
    d = latlong_directions(h, w)
    sky = (d[..., 2:] > 0).float().expand(h, w, 3)
    cosine = d[..., 2:].clamp_min(0).expand(h, w, 3)
    normals = _unit([[0, 0, 1], [0, 0, -1], [1, 0, 0], [0.3, -0.5, 0.6], [0.2, 0.7, -0.4]])
    e_sky = sample_latlong(irradiance_map(sky), normals)
    assert torch.allclose(e_sky[:, 0], math.pi * (1 + normals[:, 2]) / 2, atol=5e-3)
    e_cos = sample_latlong(irradiance_map(cosine), normals[:2])
    assert torch.allclose(e_cos[:, 0], torch.tensor([2 * math.pi / 3, 0.0]), atol=5e-3)


def test_constant_environment_stays_constant():
    pre = prefilter_environment(torch.full((32, 64, 3), 2.5))
    for level in pre.specular:
        assert torch.allclose(level, torch.full_like(level, 2.5), rtol=1e-5)
    assert torch.allclose(pre.irradiance, torch.full_like(pre.irradiance, 2.5 * math.pi),
                          rtol=1e-5)
    assert pre.level_roughness[0] == 0.0 and pre.level_roughness[-1] == 1.0
    rows = [m.shape[0] for m in pre.specular]
    assert rows == sorted(rows, reverse=True)


# ---------------------------------------------------------------- shading

@pytest.mark.parametrize("roughness", [0.3, 0.5, 0.75, 1.0])
def test_white_furnace_matches_independent_integral(roughness):
    env = torch.ones(32, 64, 3)
    cases = [(0.2, [0.8, 0.5, 0.2], 0.0), (0.5, [0.9, 0.6, 0.3], 1.0), (0.9, [0.5, 0.5, 0.5], 0.4)]
    for n_dot_v, albedo, metal in cases:
        alb = torch.tensor([albedo])
        n = _unit([[0.2, -0.3, 0.9]])
        t = _unit(torch.linalg.cross(n, torch.tensor([[1.0, 0, 0]])))
        v = n_dot_v * n + math.sqrt(1 - n_dot_v ** 2) * t
        out = split_sum(alb, torch.tensor([[roughness]]), torch.tensor([[metal]]), n, v, env)
        f0 = 0.04 * (1 - metal) + alb * metal
        a, b = lookup_dfg(dfg_lut(), torch.tensor([n_dot_v]), torch.tensor([roughness]))
        assert torch.allclose(out - (f0 * a + b), alb * (1 - metal), atol=1e-3)  # diffuse
        i0, i1 = _specular_albedo_mc(roughness, n_dot_v)
        spec = i0 + f0 * (i1 - i0)
        assert torch.allclose(out, alb * (1 - metal) + spec, atol=1e-2), (
            roughness, n_dot_v, out, alb * (1 - metal) + spec)


def test_mirror_roughness_reflects_environment():
    env = _structured_env()
    pre = prefilter_environment(env)
    g = torch.Generator().manual_seed(5)
    n = _unit(torch.randn(200, 3, generator=g))
    v = _unit(n + 0.8 * _unit(torch.randn(200, 3, generator=g)))
    ones = torch.ones(200, 1)
    out = split_sum(torch.ones(200, 3), 0 * ones, ones, n, v, pre)
    ndv = (n * v).sum(-1, keepdim=True)
    refl = 2 * ndv * n - v
    a, b = lookup_dfg(pre.lut, ndv[:, 0].clamp(1e-4, 1), torch.zeros(200))
    assert torch.allclose(out, sample_latlong(env, refl) * (a + b)[:, None], rtol=1e-5, atol=1e-6)
    rd = _unit(refl)  # analytic env at R (the blob is smooth at 128x256)
    analytic = (0.5 + 0.4 * rd[:, :1] + 0.3 * rd[:, 1:2] + 0.2 * rd[:, 2:]
                + torch.exp(30 * (rd @ _unit([0.4, -0.6, 0.7]) - 1))[:, None]
                * torch.tensor([2.0, 1.5, 1.0]))
    assert torch.allclose(out, analytic * (a + b)[:, None], atol=2e-2)


def test_raw_envmap_is_prefiltered_once(monkeypatch):
    relight.clear_prefilter_cache()
    calls = []
    real = relight.prefilter_environment
    monkeypatch.setattr(relight, "prefilter_environment",
                        lambda e, **kw: calls.append(1) or real(e, **kw))
    env = _structured_env(16, 32)
    px = dict(albedo=torch.rand(5, 4, 3), roughness=torch.rand(5, 4, 1),
              metallic=torch.rand(5, 4, 1), normal=_unit(torch.randn(5, 4, 3)),
              view_dir=_unit(torch.randn(5, 4, 3)))
    first = split_sum(envmap=env, **px)
    second = split_sum(envmap=env.clone(), **px)
    assert len(calls) == 1 and torch.equal(first, second) and first.shape == (5, 4, 3)
    env[0, 0] += 1.0
    split_sum(envmap=env, **px)
    assert len(calls) == 2


def test_bad_shapes_raise():
    env = torch.ones(16, 32, 3)
    good = dict(albedo=torch.rand(4, 4, 3), roughness=torch.rand(4, 4, 1),
                metallic=torch.rand(4, 4, 1), normal=_unit(torch.randn(4, 4, 3)),
                view_dir=_unit(torch.randn(4, 4, 3)))
    bad = [("roughness", torch.rand(4, 5, 1)), ("albedo", torch.rand(4, 4, 4)),
           ("metallic", torch.rand(4, 4)), ("normal", torch.rand(16, 3)),
           ("view_dir", torch.rand(4, 4, 2))]
    for name, value in bad:
        with pytest.raises(ValueError):
            split_sum(envmap=env, **{**good, name: value})
    for env_bad in (torch.ones(16, 32), torch.ones(16, 32, 4)):
        with pytest.raises(ValueError):
            split_sum(envmap=env_bad, **good)
    with pytest.raises(ValueError):
        sample_latlong(env, torch.ones(5, 2))
    with pytest.raises(ValueError):
        prefilter_environment(env, level_roughness=(0.0, 0.5))


# ---------------------------------------------------------------- DFG table

def test_lut_range_and_cache():
    lut = dfg_lut()
    assert lut.shape == (128, 128, 2) and dfg_lut() is lut
    assert lut.min() >= 0 and lut.max() <= 1
    assert (lut.sum(-1) <= 1 + 1e-4).all()


def test_lut_grazing_behaviour_at_high_roughness():
    # With height-correlated Smith, int f cos at alpha ~ 1 GROWS towards grazing
    # (0.31 = 1 - ln 2 at NdotV = 1, ~0.95 at NdotV -> 0); the independent integral
    # agrees, so the table must be monotone *decreasing* in NdotV on its last row.
    total = dfg_lut()[-1].sum(-1)
    assert (total[1:] <= total[:-1] + 1e-4).all() and total[0] > 0.9 and total[-1] < 0.35
    exact = _dfg_rows(torch.tensor([1.0]), torch.tensor([1.0]), hammersley(4096, torch.float32))
    assert abs(float(exact.sum()) - (1 - math.log(2))) < 2e-3
    assert abs(_specular_albedo_mc(1.0, 1 - 1e-9)[1] - (1 - math.log(2))) < 2e-3


@pytest.mark.parametrize("roughness,n_dot_v", [(0.25, 0.3), (0.5, 0.5), (0.75, 0.8),
                                               (0.9, 0.15)])
def test_lut_spot_values_match_independent_integral(roughness, n_dot_v):
    a, b = lookup_dfg(dfg_lut(), torch.tensor(n_dot_v), torch.tensor(roughness))
    i0, i1 = _specular_albedo_mc(roughness, n_dot_v)
    assert abs(float(b) - i0) < 4e-3
    assert abs(float(a + b) - i1) < 6e-3
