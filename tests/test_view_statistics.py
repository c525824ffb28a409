"""The per-point cross-view radiance statistic (issue 52) against a hand computation on a
two-view toy: two pinhole cameras looking down -z at a point, one sees it dull, one bright."""
import numpy as np
import pytest

from gspi.stage2.data import LatticeCameras
from gspi.stage2.view_statistics import FIELDS, LUMINANCE, chroma, cross_view_radiance, radiance_statistics


def two_view_toy(colours):
    """Two identical 4x4 cameras at the origin looking at +z (OpenCV), depth 2 everywhere;
    view v's image is the colour ``colours[v]`` everywhere."""
    K = np.array([[4.0, 0, 2.0], [0, 4.0, 2.0], [0, 0, 1]])
    cams = LatticeCameras(K=np.stack([K, K]), w2c=np.stack([np.eye(4), np.eye(4)]), width=4, height=4)
    images = np.stack([np.broadcast_to(np.asarray(c, np.float64), (4, 4, 3)) for c in colours])
    depth = np.full((2, 4, 4), 2.0)
    return images, depth, cams


def test_two_views_by_hand():
    dull, bright = (0.2, 0.1, 0.05), (1.5, 1.2, 1.0)
    images, depth, cams = two_view_toy([dull, bright])
    xyz = np.array([[0.1, -0.1, 2.0]])  # on the depth map in both views
    out = cross_view_radiance(images, depth, cams, xyz)
    l_dull = 0.2126 * 0.2 + 0.7152 * 0.1 + 0.0722 * 0.05
    l_bright = 0.2126 * 1.5 + 0.7152 * 1.2 + 0.0722 * 1.0
    median_lum = (l_dull + l_bright) / 2  # numpy's median of two values is their mean
    median_rgb = np.array([(0.2 + 1.5) / 2, (0.1 + 1.2) / 2, (0.05 + 1.0) / 2])
    median_chroma = median_rgb / (median_rgb @ LUMINANCE)
    assert out.shape == (1, len(FIELDS))
    np.testing.assert_allclose(out[0, 0], l_bright - median_lum, rtol=1e-6)
    np.testing.assert_allclose(out[0, 1], abs(l_bright - l_dull) / 2, rtol=1e-6)  # std of two values
    np.testing.assert_allclose(out[0, 2:], np.array(bright) / l_bright - median_chroma, rtol=1e-5)


def test_a_point_off_the_surface_or_seen_once_gets_zeros():
    images, depth, cams = two_view_toy([(0.2, 0.2, 0.2), (0.9, 0.9, 0.9)])
    depth_one = depth.copy()
    depth_one[1] = 5.0  # view 1 sees something else in front of/behind the point
    xyz = np.array([[0.0, 0.0, 2.0]])
    np.testing.assert_array_equal(cross_view_radiance(images, depth_one, cams, xyz), 0.0)
    np.testing.assert_array_equal(cross_view_radiance(images, depth, cams, np.array([[0.0, 0.0, 5.0]])), 0.0)
    assert cross_view_radiance(images, depth, cams, xyz)[0, 0] > 0


def test_a_matte_grey_and_a_metal_highlight():
    """Alike in every view: no gain, no spread, no tint. A highlight in the body's own colour
    (metal) has no tint; a white one on a red body (dielectric) tints toward white."""
    seen = np.ones((3, 1), bool)
    flat = radiance_statistics(np.full((3, 1, 3), 0.4), seen)
    np.testing.assert_allclose(flat, 0.0, atol=1e-12)
    red = np.array([0.5, 0.1, 0.1])
    metal = radiance_statistics(np.stack([red, red, 4 * red])[:, None], seen)
    np.testing.assert_allclose(metal[0, 2:], 0.0, atol=1e-6)
    assert metal[0, 0] > 0
    dielectric = radiance_statistics(np.stack([red, red, red + 1.0])[:, None], seen)
    assert dielectric[0, 2] < 0 < dielectric[0, 3]  # less red, more green than the body's chroma


@pytest.mark.parametrize("rgb", [(0.0, 0.0, 0.0), (0.3, 0.6, 0.9)])
def test_chroma_has_unit_luminance_or_is_zero(rgb):
    c = chroma(np.array(rgb))
    assert c @ LUMINANCE == pytest.approx(0.0 if max(rgb) == 0 else 1.0)


def test_neighbourhood_mean_equals_a_brute_force_k_nearest_mean():
    from gspi.stage2.view_statistics import neighbourhood_mean

    rng = np.random.default_rng(0)
    subset, values, query = rng.random((200, 3)), rng.random((200, 4)), rng.random((50, 3))
    dist = np.linalg.norm(query[:, None] - subset[None], axis=2)
    expected = values[np.argsort(dist, axis=1)[:, :7]].mean(axis=1)
    np.testing.assert_allclose(neighbourhood_mean(subset, values, query, 7, chunk=16), expected, rtol=1e-5)


def test_neighbourhood_subset_is_seeded_and_a_share_of_the_cloud():
    from gspi.stage2.view_statistics import NEIGHBOURHOOD_POINTS, neighbourhood_subset

    sub = neighbourhood_subset(5 * NEIGHBOURHOOD_POINTS)
    assert len(sub) == len(np.unique(sub)) == NEIGHBOURHOOD_POINTS and np.all(np.diff(sub) > 0)
    np.testing.assert_array_equal(sub, neighbourhood_subset(5 * NEIGHBOURHOOD_POINTS))
    np.testing.assert_array_equal(neighbourhood_subset(100), np.arange(100))  # fewer points: all of them


def test_neighbourhood_condition_pools_the_statistic_and_top_rgb(monkeypatch):
    """With every k beyond the cloud, each point gets the object's means: of the statistic (here a
    stand-in per point) and of Top-RGB, once per k, in that order."""
    from gspi.stage2 import view_statistics as vs

    rng = np.random.default_rng(1)
    xyz, top = rng.random((40, 3)), rng.random((40, 3)).astype(np.float32)
    stat = rng.random((40, 5)).astype(np.float32)
    monkeypatch.setattr(vs, "radiance_condition", lambda images, depth, cams, pts, tol_pixels: stat[:len(pts)])
    monkeypatch.setattr(vs, "NEIGHBOURHOOD_KS", (1, 1000))
    out = vs.neighbourhood_condition(None, None, None, xyz, top)
    assert out.shape == (40, 16)
    np.testing.assert_allclose(out[:, :8], np.concatenate([stat, top], axis=1), rtol=1e-6)  # k=1: itself
    np.testing.assert_allclose(out[:, 8:], np.broadcast_to(np.concatenate([stat.mean(0), top.mean(0)]), (40, 8)),
                               rtol=1e-5)


def test_a_point_outside_the_subset_takes_its_nearest_subset_points_means(monkeypatch):
    from gspi.stage2 import view_statistics as vs

    rng = np.random.default_rng(2)
    xyz, top = rng.random((60, 3)), rng.random((60, 3)).astype(np.float32)
    monkeypatch.setattr(vs, "NEIGHBOURHOOD_POINTS", 12)
    monkeypatch.setattr(vs, "radiance_condition", lambda images, depth, cams, pts, tol_pixels: pts[:, :1].repeat(5, 1))
    sub_xyz, rows = vs.neighbourhood_table(None, None, None, xyz, top)
    assert sub_xyz.shape == (12, 3) and rows.shape == (12, vs.NEIGHBOURHOOD_WIDTH)
    out = vs.neighbourhood_condition(None, None, None, xyz, top)
    nearest = np.argmin(np.linalg.norm(xyz[:, None] - sub_xyz[None], axis=2), axis=1)
    np.testing.assert_allclose(out, rows[nearest], rtol=1e-6)


def test_neighbourhood_mean_averages_the_k_nearest_points_itself_included():
    from gspi.stage2.view_statistics import neighbourhood_mean

    xyz = np.array([[0.0, 0, 0], [1, 0, 0], [10, 0, 0], [11, 0, 0]])
    values = np.array([[1.0], [3.0], [10.0], [20.0]])
    # k=2: each point with its nearest neighbour, the two pairs kept apart
    np.testing.assert_allclose(neighbourhood_mean(xyz, values, xyz, 2)[:, 0], [2, 2, 15, 15])
    # k beyond n: every point gets the mean of all
    np.testing.assert_allclose(neighbourhood_mean(xyz, values, xyz, 99)[:, 0], np.full(4, 8.5))
    # k=1: the point itself
    np.testing.assert_allclose(neighbourhood_mean(xyz, values, xyz, 1), values)
