"""experiments.condition_swap.condition_swap: each variant swaps exactly one input to the asset's renders."""
from __future__ import annotations

import json

import numpy as np

from eval.common.layout import read_scene, read_view_file
from gspi.data.pool.asset_conditions import LATTICE_SPLIT
from experiments.condition_swap.condition_swap import write_variant
from tests.stage2_fixtures import make_lattice_scene


def test_each_variant_swaps_one_input(tmp_path):
    root = make_lattice_scene(tmp_path / "data", "sphere", seed=3)
    scene = read_scene(root)
    views = [v.id for v in scene.split_views(LATTICE_SPLIT)]
    rng = np.random.default_rng(0)
    asset = rng.random((len(views), scene.height, scene.width, 3)).astype(np.float32)
    gt = np.load(root / "gt_points.npz")

    top = write_variant("asset_top_rgb", root, asset, tmp_path / "swap") / root.name
    pts = np.load(top / "gt_points.npz")
    rows, cols = gt["pixel"][:, 0], gt["pixel"][:, 1]
    np.testing.assert_array_equal(pts["rgb"], asset[gt["view"], rows, cols].astype(gt["rgb"].dtype))
    for key in ("xyz", "view", "pixel", "albedo", "metallic"):
        np.testing.assert_array_equal(pts[key], gt[key])
    first = top / LATTICE_SPLIT / views[0] / "rgb.exr"
    assert first.is_symlink() or (top / LATTICE_SPLIT).is_symlink()  # the prior's images untouched

    prior = write_variant("asset_prior", root, asset, tmp_path / "swap") / root.name
    assert (prior / "gt_points.npz").is_symlink()  # Top-RGB untouched
    for k in (0, len(views) - 1):
        d = prior / LATTICE_SPLIT / views[k]
        np.testing.assert_allclose(read_view_file(d, "rgb.exr"), asset[k], rtol=0, atol=1e-6)
        assert (d / "depth.exr").is_symlink()
    splits = json.loads((tmp_path / "swap" / "asset_prior" / "splits.json").read_text())
    assert splits["test"] == [root.name]

    plain = write_variant("gt", root, asset, tmp_path / "swap") / root.name
    assert (plain / "gt_points.npz").is_symlink() and (plain / LATTICE_SPLIT).is_symlink()
