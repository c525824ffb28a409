"""Training and inference see the same Stage II condition (issue 24, item 2).

One lattice scene is read twice: through the training path (``gt_points.npz`` ->
``gspi.stage2.data``) and through the inference path (its lattice views as Stage I's renders ->
Stage I's unprojection ``gspi.stage1.extract.unproject_renders`` -> ``gspi.stage2.infer``). A
mismatch in any of Top-RGB, source view, one-hot, A5's multi-view condition, the prior tokens or
the unit-sphere frame would look exactly like a model that "does not learn"."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gspi.stage1.extract import unproject_renders
from gspi.stage2.data import load_scene_points, local_condition
from gspi.stage2.encoders import build_encoder, lattice_images_srgb
from gspi.stage2.feature_cache import scene_feature_maps, scene_prior_features
from gspi.stage2.infer import lattice_srgb, point_conditions, prior_features
from gspi.stage2.normalize import fit_unit_sphere, to_unit_sphere
from tests.stage2_fixtures import gt_views_as_renders, make_lattice_scene


@pytest.fixture(scope="module")
def both_paths(tmp_path_factory):
    root = make_lattice_scene(tmp_path_factory.mktemp("parity"), "sphere", seed=3)
    encoder = build_encoder({"encoder": "alexnet"})
    train_scene = load_scene_points(root, scene_prior_features(root, encoder, root / "cache"),
                                    scene_feature_maps(root, encoder, root / "cache"))
    renders = gt_views_as_renders(root)
    points = unproject_renders(renders, alpha_threshold=0.5)
    return train_scene, points, renders, encoder


def test_stage1_cloud_is_the_training_cloud(both_paths):
    scene, points, _, _ = both_paths
    assert len(points) == scene.num_points
    np.testing.assert_array_equal(points.view, scene.view)
    np.testing.assert_array_equal(points.pixel, scene.pixel)
    np.testing.assert_allclose(points.xyz, scene.xyz, atol=1e-5)


@pytest.mark.parametrize("mode", ["top_rgb_onehot", "top_rgb", "multiview"])
def test_local_condition_is_the_same(both_paths, mode):
    scene, points, renders, _ = both_paths
    train = local_condition(scene, np.arange(scene.num_points), scene.xyz, mode)
    infer = point_conditions(points, mode, renders)
    assert train.shape == infer.shape
    if mode == "multiview":  # float32 vs float64 positions: a visibility test at its threshold may flip
        assert np.mean(np.abs(train - infer) > 1e-5) < 1e-3
    else:
        np.testing.assert_allclose(infer, train, atol=1e-6)
    if mode == "top_rgb_onehot":
        np.testing.assert_array_equal(np.argmax(infer[:, 3:], axis=1), scene.view)


def test_prior_tokens_are_the_same(both_paths):
    scene, _, renders, encoder = both_paths
    at_inference = prior_features(encoder, renders.rgb)        # [32, D, 5, 5] from the renders
    torch.testing.assert_close(lattice_srgb(renders.rgb), lattice_images_srgb(scene.root))  # encoder input
    np.testing.assert_allclose(at_inference.numpy(), scene.prior_grid().numpy(), rtol=1e-5, atol=1e-5)


def test_unit_sphere_frame_is_the_same(both_paths):
    scene, points, _, _ = both_paths
    frame = fit_unit_sphere(torch.as_tensor(points.xyz, dtype=torch.float64))  # predict_point_pbr's frame=None
    a = to_unit_sphere(torch.from_numpy(scene.xyz), scene.frame)
    b = to_unit_sphere(torch.as_tensor(points.xyz, dtype=torch.float64), frame)
    torch.testing.assert_close(b, a, atol=1e-5, rtol=0)


@pytest.mark.parametrize("mode", ["top_rgb_onehot", "top_rgb"])
def test_pixel_features_are_the_same(both_paths, mode):
    """stage2.data.pixel_features: the map sampled at the source pixel, from the GT views in
    training and from the renders at inference, appended after the same base condition."""
    scene, points, renders, encoder = both_paths
    maps = encoder.encode_map(lattice_srgb(renders.rgb))
    np.testing.assert_allclose(maps.numpy(), scene.feature_maps.numpy(), rtol=1e-5, atol=1e-5)
    train = local_condition(scene, np.arange(scene.num_points), scene.xyz, mode, pixel_features=True)
    infer = point_conditions(points, mode, renders, feature_maps=maps)
    base = local_condition(scene, np.arange(scene.num_points), scene.xyz, mode)
    assert train.shape == infer.shape == (scene.num_points, base.shape[1] + encoder.feature_dim)
    np.testing.assert_array_equal(train[:, :base.shape[1]], base)
    np.testing.assert_allclose(infer, train, rtol=1e-4, atol=1e-4)


def test_pixel_feature_spread_is_the_same(both_paths):
    """stage2.data.pixel_feature_spread: the map's spread over the views that see a point, from the
    GT views and GT depth in training, from the renders and their depth at inference."""
    scene, points, renders, encoder = both_paths
    maps = encoder.encode_map(lattice_srgb(renders.rgb))
    idx = np.arange(scene.num_points)
    train = local_condition(scene, idx, scene.xyz, "top_rgb_onehot", pixel_feature_spread=True)
    infer = point_conditions(points, "top_rgb_onehot", renders, feature_maps=maps, pixel_features=False,
                             pixel_feature_spread=True)
    assert train.shape == infer.shape == (scene.num_points, 35 + encoder.feature_dim)
    assert np.abs(train[:, 35:]).max() > 0  # the views disagree somewhere: the test is not of zeros
    # float32 vs float64 positions: a visibility test at its threshold may flip for a few points
    close = np.isclose(infer, train, rtol=1e-4, atol=1e-4).all(axis=1)
    assert close.mean() > 0.99


def test_cross_view_radiance_is_the_same(both_paths):
    """stage2.data.cross_view_radiance (issue 52): from the GT lattice views and depth in training,
    from the renders' linear radiance and depth at inference, appended after the base condition."""
    scene, points, renders, _ = both_paths
    idx = np.arange(scene.num_points)
    train = local_condition(scene, idx, scene.xyz, "top_rgb_onehot", cross_view_radiance=True)
    infer = point_conditions(points, "top_rgb_onehot", renders, cross_view_radiance=True)
    assert train.shape == infer.shape == (scene.num_points, 35 + 5)
    np.testing.assert_allclose(infer[:, :35], train[:, :35], atol=1e-6)
    differ = np.abs(infer[:, 35:] - train[:, 35:]).max(axis=1) > 1e-4  # float32 positions: a visibility may flip
    assert differ.mean() < 2e-3
    assert np.abs(train[:, 35:]).max() > 0  # the fixture's views differ: the statistic is not all zero


def test_cross_view_neighbourhood_is_the_same(both_paths):
    """stage2.data.cross_view_neighbourhood (issue 52, session 26): the statistic's and Top-RGB's
    neighbourhood means, over the GT cloud's seeded subset in training and Stage I's at inference,
    appended after the per-point statistic."""
    scene, points, renders, _ = both_paths
    idx = np.arange(scene.num_points)
    train = local_condition(scene, idx, scene.xyz, "top_rgb_onehot", cross_view_radiance=True,
                            cross_view_neighbourhood=True)
    infer = point_conditions(points, "top_rgb_onehot", renders, cross_view_radiance=True,
                             cross_view_neighbourhood=True)
    assert train.shape == infer.shape == (scene.num_points, 35 + 5 + 16)
    # float32 vs float64 positions: a visibility flip of one neighbour moves a mean by a 32nd of it
    close = np.isclose(infer[:, 40:], train[:, 40:], rtol=1e-3, atol=1e-4).all(axis=1)
    assert close.mean() > 0.99
    assert np.abs(train[:, 40:45]).max() > 0  # the pooled statistic is not all zero
    np.testing.assert_allclose(train[:, 45:48], np.broadcast_to(train[:, 45:48].mean(0), (scene.num_points, 3)),
                               atol=0.5)  # a Top-RGB mean, within the colour range
