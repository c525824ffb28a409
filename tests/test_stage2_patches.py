"""Patch-wise Stage II inference (issue 52, ``stage2.inference.patch_points``): the cover holds
every point, the blend is a weighted mean that leaves singly-covered points untouched, and a
patch that holds the whole cloud is whole-cloud inference, to the bit."""
import numpy as np
import pytest
import torch

from gspi.stage2.model import RCWConfig, RCWDenoiser
from gspi.stage2.patches import blend_patches, blend_weights, cover_patches, farthest_point_centres
from gspi.stage2.sampler import mean_point_pbr, predict_point_pbr

TINY = RCWConfig(num_latents=8, latent_dim=16, point_dim=16, num_blocks=1, num_compute_layers=1, num_heads=2,
                 fourier_bands=2, global_token_dim=4)


@pytest.fixture(scope="module")
def cloud():
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(300, 3))
    xyz /= np.linalg.norm(xyz, axis=1, keepdims=True)  # a sphere's surface
    cond = rng.random((300, TINY.local_cond_dim)).astype(np.float32)
    feats = torch.from_numpy(rng.normal(size=(32, 4, 5, 5)).astype(np.float32))
    torch.manual_seed(0)
    return xyz, cond, feats, RCWDenoiser(TINY).eval()


def test_cover_holds_every_point_in_patches_of_the_asked_size(cloud):
    xyz = cloud[0]
    patches, centres = cover_patches(xyz, 64, coverage=2.0, seed=3)
    assert patches.shape[1] == 64 and len(patches) >= int(np.ceil(2.0 * 300 / 64))
    assert np.array_equal(np.unique(patches), np.arange(300))
    assert all(np.all(np.diff(row) > 0) for row in patches)  # sorted, no repeats
    assert all(c in row for c, row in zip(centres, patches))  # a patch holds its centre
    again, _ = cover_patches(xyz, 64, coverage=2.0, seed=3)
    np.testing.assert_array_equal(again, patches)
    whole, _ = cover_patches(xyz, 300)
    np.testing.assert_array_equal(whole, np.arange(300)[None])
    with pytest.raises(ValueError, match="patch_points"):
        cover_patches(xyz, 0)


def test_farthest_point_centres_spread_out():
    xyz = np.array([[0.0, 0, 0], [0.1, 0, 0], [5.0, 0, 0], [0, 5.0, 0]])
    centres = farthest_point_centres(xyz, 3, seed=0)
    assert len(set(centres.tolist())) == 3 and {2, 3} <= set(centres.tolist())


def test_blend_is_the_weighted_mean_and_leaves_single_cover_alone():
    values = torch.tensor([[[1.0], [2.0]], [[3.0], [5.0]]])  # two patches of two points
    patches = np.array([[0, 1], [1, 2]])  # point 1 is in both
    weights = np.array([[1.0, 0.25], [0.75, 1.0]])
    out = blend_patches(values, patches, weights, 3)
    torch.testing.assert_close(out[:, 0], torch.tensor([1.0, (0.25 * 2 + 0.75 * 3) / 1.0, 5.0]))
    xyz = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    w = blend_weights(xyz, np.array([[0, 1, 2]]), np.array([0]))
    np.testing.assert_allclose(w[0], np.exp(-2.0 * np.array([0.0, 0.5, 1.0]) ** 2))


def test_a_patch_holding_the_whole_cloud_is_whole_cloud_inference(cloud):
    xyz, cond, feats, model = cloud
    whole = predict_point_pbr(model, xyz, cond, feats, num_steps=3, seed=5)
    one_patch = predict_point_pbr(model, xyz, cond, feats, num_steps=3, seed=5, patch_points=len(xyz))
    torch.testing.assert_close(one_patch, whole, rtol=0, atol=0)


def test_patch_inference_differs_from_whole_and_is_deterministic(cloud):
    xyz, cond, feats, model = cloud
    kw = dict(num_steps=3, seed=5, patch_points=64, patch_coverage=2.0)
    a = mean_point_pbr(model, xyz, cond, feats, patch_batch=3, **kw)
    b = mean_point_pbr(model, xyz, cond, feats, patch_batch=None, **kw)
    assert a.shape == (300, 5) and np.isfinite(a).all() and a.min() >= 0 and a.max() <= 1
    np.testing.assert_allclose(a, b, atol=1e-6)  # batching the patches changes no draw that matters
    whole = mean_point_pbr(model, xyz, cond, feats, num_steps=3, seed=5)
    assert np.abs(a - whole).max() > 1e-3  # a different context per point: not the same numbers
