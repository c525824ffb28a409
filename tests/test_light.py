"""gspi.light: the shader's affine identity, a toy whose materials the grid fit recovers exactly,
the neighbourhood pooling and posterior, the light's identification, and the records' checks."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from eval.relight import prefilter_environment
from gspi.data.environments import make_environment
from gspi.light.estimate import estimate_light
from gspi.light.observations import PointViews
from gspi.light.readout import (ROUGHNESS_GRID, MaterialGrid, fit_grid, metal_evidence, pool_neighbours, posterior,
                                read_best, read_posterior, without_metal)
from gspi.light.shading import affine_coefficients, rotate_latlong, view_terms
from tests.light_fixtures import H, shade, toy_scene, toy_views, unit


@pytest.fixture(scope="module")
def envs():
    return {name: make_environment(name, H, supersample=1) for name in ("studio_rgb", "sunset", "window_room")}


@pytest.fixture(scope="module")
def pre(envs):
    return {name: prefilter_environment(env) for name, env in envs.items()}


def test_affine_identity_equals_the_shader(pre):
    """albedo * P + Q is split_sum itself at every roughness of the grid, metal and dielectric."""
    p_env = pre["studio_rgb"]
    point, view_dir, normal = toy_views(50, 4)
    n = normal[point]
    rough = torch.as_tensor(ROUGHNESS_GRID)
    terms = view_terms(p_env, n, view_dir, rough)
    albedo = torch.rand(len(point), 3, generator=torch.Generator().manual_seed(1))
    for m in (0.0, 1.0):
        p, q = affine_coefficients(terms, m)
        for k, r in enumerate(ROUGHNESS_GRID):
            want = shade(albedo, torch.full((len(point),), r), torch.full((len(point),), m), n, view_dir, p_env)
            torch.testing.assert_close(albedo * p[k] + q[k], want, rtol=2e-5, atol=1e-5)  # float32 sums


def test_turned_directions_equal_a_rolled_map(envs):
    """Reading a map turned by psi = the map rolled by -psi W / 360 columns (a shift the coarsest
    prefiltered level also takes whole)."""
    env = envs["sunset"]
    cols = env.shape[1] // 8                       # 45 degrees
    point, view_dir, normal = toy_views(40, 3, seed=2)
    n = normal[point]
    rough = torch.tensor([0.0, 0.3, 1.0])
    turned = view_terms(prefilter_environment(env), n, view_dir, rough, rotation_deg=-360.0 * cols / env.shape[1])
    rolled = view_terms(prefilter_environment(rotate_latlong(env, cols)), n, view_dir, rough)
    torch.testing.assert_close(turned.specular, rolled.specular, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(turned.diffuse, rolled.diffuse, rtol=1e-4, atol=1e-5)


def test_grid_fit_recovers_a_toy_exactly(pre):
    obs, albedo, rough, metal = toy_scene(pre["studio_rgb"])
    grid = fit_grid(obs, pre["studio_rgb"])
    a, r, m = read_best(grid)
    assert torch.equal(m, metal)
    # roughness: exact where the views pin it (a dielectric's highlight may miss every view)
    assert (r - rough).abs().le(1e-6).float().mean() > 0.9
    assert (r - rough)[metal == 1].abs().max() < 1e-6
    torch.testing.assert_close(a[metal == 1], albedo[metal == 1], rtol=1e-3, atol=1e-3)
    assert grid.best_error().max() < 1e-4


def test_wrong_light_fits_worse(pre):
    obs, *_ = toy_scene(pre["studio_rgb"])
    right = fit_grid(obs, pre["studio_rgb"]).best_error().mean()
    wrong = fit_grid(obs, pre["sunset"]).best_error().mean()
    turned = fit_grid(obs, pre["studio_rgb"], rotation_deg=90.0).best_error().mean()
    assert wrong > 20 * right and turned > 20 * right


def test_pooling_and_posterior(pre):
    obs, *_ = toy_scene(pre["window_room"], num_points=120)
    grid = fit_grid(obs, pre["window_room"])
    torch.testing.assert_close(pool_neighbours(grid, obs.xyz, k=1), grid.error)
    pooled = pool_neighbours(grid, obs.xyz, k=8)
    assert pooled.shape == grid.error.shape
    w = posterior(pooled)
    torch.testing.assert_close(w.flatten(1).sum(1), torch.ones(len(w)))
    torch.testing.assert_close(posterior(pooled * 7.0), w)  # scale free
    a, r, m = read_posterior(grid, grid.error, temperature=1e-4)  # a sharp posterior is the best cell
    a0, r0, m0 = read_best(grid)
    assert torch.equal(m.round(), m0) and (r - r0).abs().max() < 1e-3


def test_metal_evidence_and_the_dielectric_read():
    """Two points, two roughness values, metallic (0, 1): point 0 fits metal best (0.1 against its
    best dielectric 0.2), point 1 dielectric (0.3): evidence = mean(0.2, 0.3) / mean(0.1, 0.3) = 1.25;
    over point 0 alone 2.0. Ruled out, the metal cells get no posterior weight."""
    pooled = torch.tensor([[[0.2, 0.1], [0.4, 0.5]], [[0.3, 0.6], [0.3, 0.9]]])
    metallic = torch.tensor([0.0, 1.0])
    assert metal_evidence(pooled, metallic, torch.tensor([True, True])) == pytest.approx(1.25)
    assert metal_evidence(pooled, metallic, torch.tensor([True, False])) == pytest.approx(2.0)
    assert math.isnan(metal_evidence(pooled, metallic, torch.tensor([False, False])))
    assert metal_evidence(pooled[:, :, :1].expand(2, 2, 2), metallic, torch.tensor([True, True])) == 1.0
    grid = MaterialGrid(error=pooled, albedo=torch.rand(2, 2, 2, 3), roughness=torch.tensor([0.2, 0.8]),
                        metallic=metallic, views=torch.tensor([3, 3]))
    ruled = without_metal(pooled, metallic)
    assert torch.equal(ruled[..., 0], pooled[..., 0]) and torch.isinf(ruled[..., 1]).all()
    albedo, rough, metal = read_posterior(grid, ruled)
    assert torch.equal(metal, torch.zeros(2))
    # the dielectric column's own posterior: point 0 weights exp(0), exp(-(0.4/0.2 - 1)/0.1)
    w0 = torch.softmax(torch.tensor([0.0, -10.0]), 0)
    torch.testing.assert_close(rough[0], (w0 * grid.roughness).sum())
    torch.testing.assert_close(rough[1], torch.tensor(0.5))  # two equal cells
    assert torch.equal(pooled, torch.tensor([[[0.2, 0.1], [0.4, 0.5]], [[0.3, 0.6], [0.3, 0.9]]]))  # input untouched


def test_unseen_points_take_their_neighbours():
    """A point no view sees: error 1 in its own grid, its neighbours' after pooling."""
    p_env = prefilter_environment(make_environment("studio_rgb", H, supersample=1))
    obs, *_ = toy_scene(p_env, num_points=30, views=4)
    keep = obs.point != 0
    blind = PointViews(point=obs.point[keep], colour=obs.colour[keep], view_dir=obs.view_dir[keep],
                       normal=obs.normal, xyz=obs.xyz)
    grid = fit_grid(blind, p_env)
    assert grid.views[0] == 0 and torch.all(grid.error[0] == 1.0)
    assert pool_neighbours(grid, blind.xyz, k=4)[0].max() < 1.0


def test_identifies_env_turn_and_gain(pre):
    truth = pre["sunset"]
    obs, *_ = toy_scene(truth, num_points=400, views=10, seed=3, gain=1.7, rotation_deg=65.0)
    est = estimate_light(obs, pre, max_points=300)
    assert est.env == "sunset"
    assert abs((est.rotation_deg - 65.0 + 180) % 360 - 180) <= 5.0
    assert abs(math.log2(est.gain / 1.7)) < 0.3
    assert est.margin > 2.0
    assert [h.env for h in est.ranking][0] == "sunset" and len(est.ranking) == 3


def test_coarse_search_on_fewer_points_finds_the_same_light(pre):
    """``coarse_points``: the coarse search reads a subset, the refinement all points; on the toy
    it lands on the same environment, turn and gain, and its scores are the refinement's on all
    points (the best hypothesis scored again on all of them gives the same number)."""
    from gspi.light.estimate import score

    obs, *_ = toy_scene(pre["sunset"], num_points=400, views=10, seed=3, gain=1.7, rotation_deg=65.0)
    full = estimate_light(obs, pre, max_points=300)
    fast = estimate_light(obs, pre, max_points=300, coarse_points=80)
    assert (fast.env, fast.rotation_deg, fast.gain) == (full.env, full.rotation_deg, full.gain)
    seen = np.sort(np.random.default_rng(0).choice(np.flatnonzero(obs.views_per_point().numpy() > 0), 300,
                                                   replace=False))
    again = score(obs.subset(seen), pre[fast.env], fast.rotation_deg, [fast.gain])[0]
    assert again == pytest.approx(fast.best.score, rel=1e-6)


def test_point_views_checks():
    ok = dict(point=torch.tensor([0, 1]), colour=torch.ones(2, 3), view_dir=unit(torch.ones(2, 3)),
              normal=unit(torch.ones(2, 3)), xyz=torch.zeros(2, 3))
    PointViews(**ok)
    with pytest.raises(ValueError, match="one row per observation"):
        PointViews(**{**ok, "colour": torch.ones(3, 3)})
    with pytest.raises(ValueError, match=r"point indices must lie in \[0, 2\)"):
        PointViews(**{**ok, "point": torch.tensor([0, 2])})
    with pytest.raises(ValueError, match="NaN or inf"):
        PointViews(**{**ok, "colour": torch.tensor([[0.0, float("nan"), 0], [1, 1, 1]])})
    with pytest.raises(ValueError, match="at least one candidate"):
        estimate_light(PointViews(**ok), {})
    sub = PointViews(**ok).subset(np.array([1]))
    assert sub.num_points == 1 and sub.point.tolist() == [0]


def test_normal_search_recovers_materials_under_tilted_normals(pre):
    """Normals given 6 degrees off (as a reconstructed cloud's): the plain fit misreads metal
    roughness (a quarter exact); the search, whose first ring holds the true normal, picks it for
    most points on its coarse roughness grid (a rough dielectric barely pins it) and then reads
    nine in ten metals' roughness exactly, the class of (nearly) every point."""
    from gspi.light.readout import cone_normals, fit_grid_normal_search, refine_normals

    p_env = pre["studio_rgb"]
    obs, albedo, rough, metal = toy_scene(p_env, num_points=200)
    given = unit(obs.normal + 0.3 * unit(torch.randn(200, 3, generator=torch.Generator().manual_seed(5))))
    true = cone_normals(given, (6.0,))[1]  # 6 degrees from the given normal
    angle = torch.rad2deg(torch.acos((true * given).sum(-1).clamp(-1, 1)))
    torch.testing.assert_close(angle, torch.full_like(angle, 6.0), atol=1e-3, rtol=0)
    colour = shade(albedo[obs.point], rough[obs.point], metal[obs.point], true[obs.point], obs.view_dir, p_env)
    tilted = PointViews(point=obs.point, colour=colour, view_dir=obs.view_dir, normal=given, xyz=obs.xyz)
    found = refine_normals(tilted, p_env, rings_deg=(6.0,))
    picked = (found - true).norm(dim=-1).lt(1e-5)
    assert picked.float().mean() > 0.75 and picked[metal == 1].float().mean() > 0.85
    plain = fit_grid(tilted, p_env)
    searched = fit_grid_normal_search(tilted, p_env, rings_deg=(6.0,))
    assert searched.best_error().lt(1e-4).float().mean() > 0.85 > 0.3 > plain.best_error().lt(1e-4).float().mean()
    _, r, m = read_best(searched)
    assert (m == metal).float().mean() >= 0.99
    exact = lambda r_: (r_ - rough)[metal == 1].abs().lt(1e-6).float().mean()  # noqa: E731
    assert exact(r) > 0.85 > 0.4 > exact(read_best(plain)[1])


def test_normal_profile_takes_each_cells_best_normal(pre):
    """``profile`` k: every cell is the best of the k ranked normals' fits, so no cell's error
    exceeds the single refined normal's, and each cell's albedo is the fit of the normal whose
    error it took (checked against fits made here one normal at a time)."""
    from gspi.light.readout import fit_grid_normal_search, min_over_normals, rank_normals

    p_env = pre["studio_rgb"]
    obs, albedo, rough, metal = toy_scene(p_env, num_points=120)
    given = unit(obs.normal + 0.3 * unit(torch.randn(120, 3, generator=torch.Generator().manual_seed(7))))
    tilted = PointViews(point=obs.point, colour=obs.colour, view_dir=obs.view_dir, normal=given, xyz=obs.xyz)
    single = fit_grid_normal_search(tilted, p_env, rings_deg=(6.0,))
    profiled = fit_grid_normal_search(tilted, p_env, rings_deg=(6.0,), profile=3)
    assert (profiled.error <= single.error + 1e-7).all() and (profiled.error < single.error - 1e-4).any()
    candidates, order = rank_normals(tilted, p_env, rings_deg=(6.0,))
    assert order.shape == (7, 120) and sorted(order[:, 0].tolist()) == list(range(7))
    rows = torch.arange(120)
    fits = [fit_grid(replace(tilted, normal=candidates[order[j], rows]), p_env) for j in range(3)]
    torch.testing.assert_close(profiled.error, torch.stack([f.error for f in fits]).min(dim=0).values)
    which = torch.stack([f.error for f in fits]).argmin(dim=0)
    for j, f in enumerate(fits):
        torch.testing.assert_close(profiled.albedo[which == j], f.albedo[which == j])
    torch.testing.assert_close(min_over_normals([single]).error, single.error)
    with pytest.raises(ValueError, match="profile=0"):
        fit_grid_normal_search(tilted, p_env, rings_deg=(6.0,), profile=0)


def test_a_light_is_told_when_it_stands_out_from_the_next():
    from gspi.light.estimate import TOLD_MARGIN, Hypothesis, LightEstimate

    best = Hypothesis("sunset", 0.0, 1.0, 0.1)
    assert LightEstimate(best=best, margin=TOLD_MARGIN).told and LightEstimate(best=best, margin=float("inf")).told
    assert not LightEstimate(best=best, margin=1.01).told
