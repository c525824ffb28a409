"""Stage I: lattice rendering, unprojection, the three filters, the source-view binding."""
import numpy as np
import pytest
import torch

from gspi.stage1 import filters
from gspi.stage1.extract import Stage1Config, extract_point_cloud
from gspi.point_cloud import PointCloud, local_condition
from tests.fixtures import surfel_sphere

RADIUS = 0.8


@pytest.fixture(scope="module")
def clean():
    torch.set_num_threads(1)
    cfg = Stage1Config(image_size=48)
    return extract_point_cloud(surfel_sphere(radius=RADIUS), cfg)


def test_points_lie_on_the_surface(clean):
    points, _, stats = clean
    r = np.linalg.norm(points.xyz, axis=-1)
    assert len(points) > 1000
    # at 48 px a pixel is 0.05 world units wide: grazing silhouette pixels dominate the tail
    assert np.median(np.abs(r - RADIUS)) < 0.02
    assert stats["filters"][-1]["step"] == "depth_consensus"


def test_filters_keep_a_clean_surface(clean):
    _, _, stats = clean
    unprojected = stats["filters"][0]["count"]
    assert stats["num_points"] > 0.95 * unprojected


def test_source_binding_projects_back_to_the_pixel(clean):
    points, renders, _ = clean
    rc, _ = filters.project(points.xyz.astype(np.float64), renders.K, renders.w2c)
    own = rc[points.view, np.arange(len(points))]
    np.testing.assert_allclose(own, points.pixel + 0.5, atol=1e-3)
    # the stored RGB is the render's value at that pixel of that view
    np.testing.assert_array_equal(points.rgb, renders.rgb[points.view, points.pixel[:, 0],
                                                          points.pixel[:, 1]])


def test_local_condition_is_top_rgb_and_view_onehot(clean):
    points, _, _ = clean
    cond = local_condition(points)
    assert cond.shape == (len(points), 35)
    assert torch.equal(cond[:, 3:].argmax(-1), torch.from_numpy(points.view).long())
    assert float(cond[:, :3].min()) >= 0 and float(cond[:, :3].max()) <= 1
    assert local_condition(points, with_view_onehot=False).shape == (len(points), 3)


def _inject(points, renders, xyz_out):
    """Points appended with a random source view and the pixel they project to there."""
    n = len(xyz_out)
    view = np.arange(n, dtype=np.int32) % len(renders.K)
    rc, _ = filters.project(xyz_out, renders.K, renders.w2c)
    pix = np.floor(rc[view, np.arange(n)]).astype(np.int32)
    return (np.r_[points.xyz, xyz_out.astype(np.float32)], np.r_[points.view, view],
            np.r_[points.pixel, pix])


def test_mask_consistency_removes_free_space_points(clean):
    points, renders, _ = clean
    rng = np.random.default_rng(0)
    d = rng.normal(size=(200, 3))
    out = d / np.linalg.norm(d, axis=-1, keepdims=True) * rng.uniform(1.0, 1.4, (200, 1))
    xyz, view, _ = _inject(points, renders, out)
    keep = filters.mask_consistency_keep(xyz, view, renders.alpha, renders.K, renders.w2c)
    assert keep[:len(points)].mean() > 0.99      # the surface stays
    assert keep[len(points):].mean() < 0.05      # points off the silhouettes go


def test_depth_consensus_removes_points_in_front_of_the_surface(clean):
    points, renders, _ = clean
    rng = np.random.default_rng(1)
    idx = rng.choice(len(points), 300, replace=False)
    centre = np.linalg.inv(renders.w2c[points.view[idx]])[:, :3, 3]
    # pull surface points 15% of the way toward their source camera: floaters in free space
    out = points.xyz[idx] + 0.15 * (centre - points.xyz[idx])
    xyz = np.r_[points.xyz, out]
    view = np.r_[points.view, points.view[idx]]
    keep = filters.depth_consensus_keep(xyz, view, renders.depth, renders.alpha, renders.K,
                                        renders.w2c)
    assert keep[:len(points)].mean() > 0.99
    assert keep[len(points):].mean() < 0.1


def test_statistical_outliers_on_synthetic_cloud():
    rng = np.random.default_rng(0)
    plane = np.c_[rng.uniform(-1, 1, (2000, 2)), np.zeros(2000)]
    outliers = rng.uniform(-1, 1, (20, 3)) + np.array([0, 0, 2.0])
    keep = filters.statistical_outliers_keep(np.r_[plane, outliers], k=8, std_ratio=2.0)
    assert not keep[2000:].any() and keep[:2000].mean() > 0.97


def test_mask_consistency_rejects_points_outside_other_silhouettes():
    from gspi.data.lattice import lattice_cameras
    K, w2c = lattice_cameras(width=32, height=32)
    alpha = np.ones((32, 32, 32), dtype=np.float32)
    alpha[:, :, :4] = 0  # a background strip on the left of every view
    rc, _ = filters.project(np.zeros((1, 3)), K, w2c)
    assert np.allclose(rc[:, 0], 16.0)  # the origin projects to the image centre
    keep = filters.mask_consistency_keep(np.zeros((1, 3)), np.array([0]), alpha, K, w2c)
    assert keep.all()
    keep = filters.mask_consistency_keep(np.zeros((1, 3)), np.array([0]), np.zeros_like(alpha),
                                         K, w2c)
    assert not keep.any()


def test_point_cloud_round_trip_and_errors(clean, tmp_path):
    points, _, _ = clean
    loaded = PointCloud.load(points.save(tmp_path / "points.npz"))
    for name in ("xyz", "view", "pixel", "rgb"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(points, name))
    np.savez(tmp_path / "bad.npz", xyz=points.xyz)
    with pytest.raises(ValueError, match="bad.npz: not a Stage I point cloud"):
        PointCloud.load(tmp_path / "bad.npz")


def test_nearest_surface_depth_window_reads_the_near_side_of_an_edge():
    depth = np.array([[[2.0, 2.0, 4.0, 4.0]] * 3], dtype=np.float32)  # [1, 3, 4]: near | far
    alpha = np.ones_like(depth)
    alpha[0, :, 3] = 0  # background column: no surface there
    exact = filters.nearest_surface_depth(depth, alpha, alpha_threshold=0.5, window_px=0)
    np.testing.assert_array_equal(exact[0, 1], [2.0, 2.0, 4.0, np.inf])
    window = filters.nearest_surface_depth(depth, alpha, alpha_threshold=0.5, window_px=1)
    # the far pixel next to the edge now reports the near surface; background stays inf only
    # where no foreground pixel is within 1 px
    np.testing.assert_array_equal(window[0, 1], [2.0, 2.0, 2.0, 4.0])


def test_an_asset_seen_by_few_lattice_views_is_refused():
    """A small object far off-centre (mostly outside the lattice's frames) must not become a
    cloud of a few views that runs to "complete" (issue 17, class 5)."""
    from gspi.stage1.extract import check_cloud_covers_lattice

    asset = surfel_sphere(200, radius=0.2)
    asset.means.data += torch.tensor([4.0, 0.0, 0.0], dtype=asset.means.dtype)   # outside the rig: 6 views
    off = {"enabled": False}
    cfg = Stage1Config.from_dict({"image_size": 16, "outliers": off, "mask_consistency": off,
                                  "depth_consensus": off})
    with pytest.raises(ValueError, match=r"from \d+ of 32 lattice views"):
        extract_point_cloud(asset, cfg)
    _, renders, _ = extract_point_cloud(surfel_sphere(200, radius=RADIUS), cfg)
    few = PointCloud(xyz=np.zeros((3, 3), np.float32), view=np.int32([0, 1, 2]),
                     pixel=np.zeros((3, 2), np.int32), rgb=np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match="from 3 of 32"):
        check_cloud_covers_lattice(few, renders)


def test_filters_equal_their_all_views_at_once_definition(clean):
    """Filters (ii) and (iii) run view by view (and (iii) only on the points whose source view has
    the view as a neighbour); the keep-masks equal the [V, P] formulation written out here,
    for max_violations 0..3, on the surface plus points pushed off it both ways."""
    points, renders, _ = clean
    rng = np.random.default_rng(2)
    idx = rng.choice(len(points), 400, replace=False)
    moved = points.xyz[idx] * rng.uniform(0.9, 1.15, (400, 1)).astype(np.float32)
    xyz, view = np.r_[points.xyz, moved], np.r_[points.view, points.view[idx]]
    K, w2c, alpha = renders.K, renders.w2c, renders.alpha
    rc, z = filters.project(xyz, K, w2c)                                      # [V, P]
    fg = torch.nn.functional.max_pool2d(torch.from_numpy(alpha >= 0.5).float()[:, None], 3, 1, 1)
    fg_at, inside = filters._lookup(fg[:, 0].numpy() > 0.5, rc)
    seen = inside & (z > 0)
    seen[view, np.arange(len(xyz))] = False
    mask_violations = (seen & ~fg_at).sum(0)
    surface = filters.nearest_surface_depth(renders.depth, alpha, alpha_threshold=0.5, window_px=1)
    d_at, inside = filters._lookup(surface, rc)
    in_front = inside & (z > 0) & np.isfinite(d_at) & (z < d_at - 3.0 * z / K[:, 0, 0][:, None])
    nb = filters.neighbour_views(w2c, 6)
    is_nb = np.zeros_like(in_front)
    for col in range(6):
        is_nb[nb[view, col], np.arange(len(xyz))] = True
    depth_violations = (in_front & is_nb).sum(0)
    assert depth_violations.max() >= 2 and mask_violations.max() >= 2  # the counts are exercised
    for m in range(4):
        np.testing.assert_array_equal(
            filters.mask_consistency_keep(xyz, view, alpha, K, w2c, max_violations=m), mask_violations <= m)
        np.testing.assert_array_equal(
            filters.depth_consensus_keep(xyz, view, renders.depth, alpha, K, w2c, max_violations=m),
            depth_violations <= m)
