"""gspi.light.refine: a light in no candidate set, refined from the best candidate (issue 66, item 2b)."""
from __future__ import annotations

import pytest
import torch

from eval.relight import prefilter_environment
from gspi.data.environments import make_environment
from gspi.light.readout import fit_grid, read_best
from gspi.light.refine import cell_maps, design, refine_light
from gspi.light.shading import turn_directions
from tests.light_fixtures import H, shade, toy_scene


@pytest.fixture(scope="module")
def envs():
    return {name: make_environment(name, H, supersample=1) for name in ("studio_rgb", "sunset", "window_room")}


def test_the_prefiltered_environment_is_linear_in_the_map(envs):
    """What the refinement rests on: irradiance and every specular level of a*X + b*Y are a*pre(X) + b*pre(Y)."""
    x, y = envs["sunset"], envs["window_room"]
    mix, px, py = prefilter_environment(0.3 * x + 2.0 * y), prefilter_environment(x), prefilter_environment(y)
    torch.testing.assert_close(mix.irradiance, 0.3 * px.irradiance + 2.0 * py.irradiance, rtol=1e-4, atol=1e-5)
    for level, (m, a, b) in enumerate(zip(mix.specular, px.specular, py.specular)):
        torch.testing.assert_close(m, 0.3 * a + 2.0 * b, rtol=1e-4, atol=1e-5, msg=f"level {level}")


def test_the_design_is_the_shader_under_each_basis_map(envs):
    """A column of the design is split_sum itself under that map, turned, at each point's material."""
    x, y = prefilter_environment(envs["sunset"]), prefilter_environment(envs["window_room"])
    obs, albedo, rough, metal = toy_scene(x, num_points=60, views=5, seed=5)
    phi = design(obs, [x, y], albedo, rough, metal, rotation_deg=30.0)
    p = obs.point
    for k, env in enumerate((x, y)):
        want = shade(albedo[p], rough[p], metal[p], turn_directions(obs.normal[p], 30.0),
                     turn_directions(obs.view_dir, 30.0), env)
        torch.testing.assert_close(phi[:, k], want, rtol=2e-5, atol=1e-5)


def test_cells_tile_the_sphere_once():
    cells = torch.stack(cell_maps(H, 2 * H, rows=4))
    assert cells.shape == (32, H, 2 * H, 3)
    torch.testing.assert_close(cells.sum(0), torch.ones(H, 2 * H, 3))


def test_a_light_in_no_set_is_refined_towards_it(envs):
    """Lit by a mix in no candidate set, the best candidate's read leaves large residuals; the
    refined map explains the views several times better and reads metal and roughness closer. The
    albedo only a little: a dielectric's diffuse colour trades with the light's (c = a E(n), each
    point's albedo fitted on its own), which only the highlights pin."""
    truth = prefilter_environment(0.5 * envs["studio_rgb"] + envs["window_room"] * torch.tensor([1.2, 0.9, 0.6]))
    obs, albedo, rough, metal = toy_scene(truth, num_points=250, views=10, seed=3)
    candidate = prefilter_environment(envs["studio_rgb"])
    refined = refine_light(obs, candidate, rotation_deg=0.0, gain=1.0)
    assert refined.score < refined.start_score / 3
    assert 0.0 < refined.candidate_share < 1.0 and bool((refined.envmap >= 0).all())

    def read(pre):
        a, r, m = read_best(fit_grid(obs, pre))
        return float((a - albedo).abs().mean()), float((r - rough).abs().mean()), float((m == metal).float().mean())

    (albedo_c, rough_c, metal_c), (albedo_r, rough_r, metal_r) = read(candidate), read(refined.pre)
    assert metal_r > metal_c + 0.05 and rough_r < 0.9 * rough_c and albedo_r < albedo_c


def test_the_right_light_is_kept(envs):
    pre = prefilter_environment(envs["sunset"])
    obs, *_ = toy_scene(pre, num_points=120, views=8, seed=4)
    refined = refine_light(obs, pre, rotation_deg=0.0, gain=1.0)
    assert refined.candidate_share == 1.0 and refined.pre is pre and refined.score == refined.start_score


def test_a_scene_no_view_sees_is_refused(envs):
    pre = prefilter_environment(envs["sunset"])
    obs, *_ = toy_scene(pre, num_points=10, views=2)
    with pytest.raises(ValueError, match="no view sees any point"):
        refine_light(obs.subset([]), pre, rotation_deg=0.0, gain=1.0)
