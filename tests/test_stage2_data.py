"""Tests of Stage II's training data (gspi/stage2/data.py) on lattice sphere scenes built in code
(tests/stage2_fixtures.py)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gspi.stage2.data import (LOCAL_CONDITIONS, PointDataConfig, feature_spread_over_views, load_scene_points,
                              local_condition, local_subset, multiview_condition, perturb_along_rays,
                              pixel_footprint, project_to_views, sample_batch, sample_pixel_features,
                              whole_scene_inputs)
from tests.stage2_fixtures import SIZE, make_lattice_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = make_lattice_scene(tmp_path_factory.mktemp("s2data"), "sphere")
    feats = torch.randn(32, 8, 5, 5, generator=torch.Generator().manual_seed(0))
    return load_scene_points(root, feats)


@pytest.mark.parametrize("mode", sorted(LOCAL_CONDITIONS))
def test_batch_shapes_per_condition(scene, mode):
    cfg = PointDataConfig(num_points=64, local_condition=mode, train_views=16)
    f0, inputs = sample_batch([scene], cfg, 3, np.random.default_rng(0))
    assert f0.shape == (3, 64, 5) and inputs.xyz.shape == (3, 64, 3)
    assert inputs.local_cond.shape == (3, 64, LOCAL_CONDITIONS[mode])  # 35 / 3 / 128
    assert inputs.global_tokens.shape == (3, 16, 25, 8) and inputs.view_ids.shape == (3, 16)
    assert f0.min() >= -1 and f0.max() <= 1
    assert inputs.local_cond[..., :3].min() >= 0 and inputs.local_cond[..., :3].max() <= 1
    ids = inputs.view_ids[0]
    torch.testing.assert_close(inputs.global_tokens[0], scene.global_tokens[ids])  # dropout keeps the ids' tokens
    assert len(set(ids.tolist())) == 16


def test_targets_and_top_rgb_follow_the_stored_values(scene, tmp_path):
    from eval.common.colorspace import linear_to_srgb

    with np.load(scene.root / "gt_points.npz") as npz:
        albedo, rough, rgb = npz["albedo"], npz["roughness"], npz["rgb"]
    np.testing.assert_allclose(scene.f0[:, :3], albedo * 2 - 1, atol=1e-6)
    np.testing.assert_allclose(scene.f0[:, 3], rough * 2 - 1, atol=1e-6)
    np.testing.assert_allclose(scene.top_rgb, linear_to_srgb(torch.from_numpy(rgb).clamp(0, 1)).numpy(), atol=1e-6)


def test_onehot_binds_lattice_camera_and_source_pixel(scene):
    """One-hot index k = lattice camera k: the point projects onto its stored pixel in camera k,
    also after the perturbation (which moves along that ray)."""
    from gspi.data.lattice import lattice_cameras

    K, w2c = lattice_cameras(num_views=32, radius=3.0, fov_deg=45.0, width=SIZE, height=SIZE)
    np.testing.assert_allclose(scene.cameras.w2c, w2c, atol=1e-6)
    idx = np.arange(scene.num_points)
    cond = local_condition(scene, idx, scene.xyz, "top_rgb_onehot")
    assert (cond[:, 3:].argmax(1) == scene.view).all() and (cond[:, 3:].sum(1) == 1).all()
    moved = perturb_along_rays(scene.xyz, scene.view, scene.cameras, sigma_pixels=0.5,
                               rng=np.random.default_rng(0))
    for xyz in (scene.xyz, moved):
        uv, _ = scene.cameras.project(xyz, scene.view)
        assert (np.floor(uv[:, 0]) == scene.pixel[:, 1]).all() and (np.floor(uv[:, 1]) == scene.pixel[:, 0]).all()


def test_perturbation_magnitude(scene):
    k = 0.5
    moved = perturb_along_rays(scene.xyz, scene.view, scene.cameras, sigma_pixels=k, rng=np.random.default_rng(1))
    centres = scene.cameras.centers[scene.view]
    d0 = np.linalg.norm(scene.xyz - centres, axis=1)
    d1 = np.linalg.norm(moved - centres, axis=1)
    z = np.einsum("ni,ni->n", scene.xyz - centres, scene.cameras.w2c[scene.view, 2, :3])
    ratio = (d1 - d0) / pixel_footprint(z, scene.cameras, scene.view)
    assert abs(ratio.mean()) < 0.05 and ratio.std() == pytest.approx(k, rel=0.08)
    offset = moved - scene.xyz  # along the source ray: parallel to (x - c)
    cross = np.cross(offset, scene.xyz - centres)
    assert np.abs(cross).max() < 1e-9
    np.testing.assert_array_equal(perturb_along_rays(scene.xyz, scene.view, scene.cameras, sigma_pixels=0.0,
                                                     rng=np.random.default_rng(1)), scene.xyz)


def test_local_subset_is_spatially_local(scene):
    rng = np.random.default_rng(0)
    n = 128
    for _ in range(5):
        idx = local_subset(scene, n, rng)
        assert len(set(idx.tolist())) == n
        pts = scene.xyz[idx]
        # the subset is a kNN ball: every other point is at least as far from its centre
        centre = pts[0]  # cKDTree returns the query point itself first
        radius = np.linalg.norm(pts - centre, axis=1).max()
        others = np.delete(np.arange(scene.num_points), idx)
        assert np.linalg.norm(scene.xyz[others] - centre, axis=1).min() >= radius - 1e-9
        assert radius < 0.5 * np.linalg.norm(scene.xyz - centre, axis=1).max()


def test_multiview_condition_visibility(scene):
    cond = multiview_condition(scene, scene.xyz, tol_pixels=2.0).reshape(-1, 32, 4)
    vis = cond[..., 3]
    assert set(np.unique(vis).tolist()) <= {0.0, 1.0}
    assert vis[np.arange(scene.num_points), scene.view].mean() > 0.99  # seen by its source view
    assert 0.2 < vis.mean() < 0.8  # a sphere: roughly half of the views see each point
    assert cond[..., :3].min() >= 0 and cond[..., :3].max() <= 1


def test_whole_scene_inputs_cover_all_points(scene):
    cfg = PointDataConfig(local_condition="top_rgb_onehot")
    xyz, cond = whole_scene_inputs(scene, cfg, np.random.default_rng(0))
    assert xyz.shape == (scene.num_points, 3) and cond.shape == (scene.num_points, 35)


def test_unknown_condition_is_rejected():
    with pytest.raises(ValueError, match="top_rgb_onehot"):
        PointDataConfig.from_mapping({"local_condition": "six_views"})


@pytest.mark.parametrize("grid, image", [((13, 13), (32, 32)), ((5, 7), (24, 40)), ((16, 16), (16, 16))])
def test_pixel_features_are_bilinear_samples_at_pixel_centres(grid, image):
    """Oracle: torch grid_sample (align_corners=False, border padding) at each pixel's centre."""
    gen = torch.Generator().manual_seed(1)
    maps = torch.randn(3, 6, *grid, generator=gen)
    rng = np.random.default_rng(0)
    n = 200
    view = rng.integers(3, size=n)
    pixel = np.stack([rng.integers(image[0], size=n), rng.integers(image[1], size=n)], axis=1)
    out = sample_pixel_features(maps, view, pixel, image)
    xy = torch.from_numpy(np.stack([(pixel[:, 1] + 0.5) / image[1], (pixel[:, 0] + 0.5) / image[0]], 1) * 2 - 1)
    oracle = torch.nn.functional.grid_sample(maps[torch.from_numpy(view)], xy.float()[:, None, None],
                                             mode="bilinear", padding_mode="border", align_corners=False)
    np.testing.assert_allclose(out, oracle[:, :, 0, 0].numpy(), rtol=1e-5, atol=1e-5)
    if grid == image:  # one cell per pixel: the sample is the cell itself
        np.testing.assert_array_equal(out, maps[view, :, pixel[:, 0], pixel[:, 1]].numpy())


def test_pixel_features_extend_the_local_condition(scene):
    maps = torch.randn(32, 8, 13, 13, generator=torch.Generator().manual_seed(2))
    with_maps = load_scene_points(scene.root, scene.prior_grid(), maps)
    cfg = PointDataConfig(num_points=64, pixel_features=True)
    assert cfg.condition_width(8) == 35 + 8 and PointDataConfig().condition_width(8) == 35
    _, inputs = sample_batch([with_maps], cfg, 2, np.random.default_rng(0))
    assert inputs.local_cond.shape == (2, 64, 43)
    idx = np.arange(10)
    cond = local_condition(with_maps, idx, with_maps.xyz[idx], "top_rgb_onehot", pixel_features=True)
    np.testing.assert_array_equal(cond[:, :35], local_condition(scene, idx, scene.xyz[idx], "top_rgb_onehot"))
    np.testing.assert_allclose(cond[:, 35:], sample_pixel_features(maps, scene.view[idx], scene.pixel[idx], (SIZE, SIZE)))
    with pytest.raises(ValueError, match="pixel_features needs the prior encoder's maps"):
        local_condition(scene, idx, scene.xyz[idx], "top_rgb_onehot", pixel_features=True)


def spread_oracle(maps: torch.Tensor, depth: np.ndarray, cams, xyz: np.ndarray, tol: float) -> np.ndarray:
    """Point by point and view by view: the depth test written out, the map sampled with
    torch's grid_sample at the pixel's centre, numpy's (population) std over the views that pass."""
    height, width = depth.shape[1:]
    out = np.zeros((len(xyz), maps.shape[1]), dtype=np.float32)
    for i, p in enumerate(xyz):
        seen = []
        for v in range(len(depth)):
            uv, z = cams.project(p[None], np.array([v]))
            col, row = int(np.floor(uv[0, 0])), int(np.floor(uv[0, 1]))
            if not (z[0] > 0 and 0 <= col < width and 0 <= row < height):
                continue
            d = depth[v, row, col]
            if not (d > 0 and abs(d - z[0]) < tol * z[0] / cams.K[v, 0, 0]):
                continue
            xy = torch.tensor([[[[(col + 0.5) / width * 2 - 1, (row + 0.5) / height * 2 - 1]]]], dtype=torch.float32)
            seen.append(torch.nn.functional.grid_sample(maps[v:v + 1], xy, mode="bilinear", padding_mode="border",
                                                        align_corners=False)[0, :, 0, 0].numpy())
        if len(seen) >= 2:
            out[i] = np.std(np.stack(seen), axis=0)
    return out


def test_feature_spread_is_the_std_over_the_views_that_see_a_point(scene):
    maps = torch.randn(32, 5, 13, 13, generator=torch.Generator().manual_seed(3))
    _, depth = scene.lattice_views()
    xyz = scene.xyz[np.random.default_rng(0).choice(scene.num_points, 60, replace=False)]
    out = feature_spread_over_views(maps, depth, scene.cameras, xyz, tol_pixels=2.0, chunk=16)
    np.testing.assert_allclose(out, spread_oracle(maps, depth, scene.cameras, xyz, 2.0), rtol=1e-4, atol=1e-5)
    assert (out > 0).all(axis=1).mean() > 0.9  # the lattice sees most points from several views
    constant = feature_spread_over_views(torch.full((32, 5, 13, 13), 2.5), depth, scene.cameras, xyz, tol_pixels=2.0)
    np.testing.assert_array_equal(constant, 0.0)  # every view alike: no spread
    uniform = torch.ones(32, 5, 13, 13) * torch.arange(32.0)[:, None, None, None]  # view v's map is v everywhere
    spread = feature_spread_over_views(uniform, depth, scene.cameras, xyz, tol_pixels=2.0)
    _, _, _, visible = project_to_views(scene.cameras, depth, xyz, tol_pixels=2.0)
    expect = np.array([np.std(np.flatnonzero(visible[:, i])) if visible[:, i].sum() >= 2 else 0.0
                       for i in range(len(xyz))])
    np.testing.assert_allclose(spread, np.repeat(expect[:, None], 5, axis=1), rtol=1e-5, atol=1e-5)


def test_feature_spread_extends_the_local_condition(scene):
    maps = torch.randn(32, 8, 13, 13, generator=torch.Generator().manual_seed(2))
    with_maps = load_scene_points(scene.root, scene.prior_grid(), maps)
    cfg = PointDataConfig(num_points=64, pixel_features=True, pixel_feature_spread=True)
    assert cfg.condition_width(8) == 35 + 8 + 8 and cfg.needs_feature_maps
    assert PointDataConfig(pixel_feature_spread=True).condition_width(8) == 43
    _, inputs = sample_batch([with_maps], cfg, 2, np.random.default_rng(0))
    assert inputs.local_cond.shape == (2, 64, 51)
    idx = np.arange(10)
    cond = local_condition(with_maps, idx, with_maps.xyz[idx], "top_rgb_onehot", pixel_features=True,
                           pixel_feature_spread=True)
    np.testing.assert_array_equal(cond[:, :43], local_condition(with_maps, idx, with_maps.xyz[idx], "top_rgb_onehot",
                                                                pixel_features=True))
    _, depth = scene.lattice_views()
    np.testing.assert_allclose(cond[:, 43:], feature_spread_over_views(maps, depth, scene.cameras, scene.xyz[idx],
                                                                       tol_pixels=2.0))
    with pytest.raises(ValueError, match="pixel_feature_spread needs the prior encoder's maps"):
        local_condition(scene, idx, scene.xyz[idx], "top_rgb_onehot", pixel_feature_spread=True)


def test_whole_object_subset_spans_the_object_and_sample_batch_uses_it(scene):
    from gspi.stage2.data import PointDataConfig, sample_batch, whole_object_subset

    rng = np.random.default_rng(0)
    n = 128
    idx = whole_object_subset(scene, n, rng)
    assert len(set(idx.tolist())) == n and np.all(np.diff(idx) > 0)
    # a uniform draw reaches about as far as the object does; a kNN ball of the same size does not
    extent = lambda pts: np.linalg.norm(pts - pts.mean(0), axis=1).max()  # noqa: E731
    assert extent(scene.xyz[idx]) > 0.8 * extent(scene.xyz)
    assert extent(scene.xyz[local_subset(scene, n, rng)]) < 0.6 * extent(scene.xyz)
    np.testing.assert_array_equal(whole_object_subset(scene, scene.num_points + 5, rng), np.arange(scene.num_points))
    cfg = PointDataConfig(num_points=n, subset="whole")
    f0, inputs = sample_batch([scene], cfg, 2, np.random.default_rng(3))
    assert f0.shape == (2, n, 5) and inputs.xyz.shape == (2, n, 3)


def test_an_unknown_subset_names_the_key():
    from gspi.stage2.data import PointDataConfig

    with pytest.raises(ValueError, match=r"stage2.data.subset must be one of \['local', 'whole'\], got 'global'"):
        PointDataConfig.from_mapping({"subset": "global"})
