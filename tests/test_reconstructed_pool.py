"""gspi.recon.reconstructed_pool: a pool whose conditions are a Stage 0 asset's lattice renders."""
from __future__ import annotations

import json

import numpy as np

from eval.common.layout import read_view_file
from gspi.data.pool.asset_conditions import LATTICE_SPLIT
from gspi.gaussians.lattice_render import render_lattice
from gspi.recon.reconstructed_pool import DONE_FILE, display_psnr, highlight_stats, reconstruct_pool, summary_table
from gspi.gaussians.ply import read_asset_ply
from tests.stage2_fixtures import make_lattice_dataset

FAST = ("recon.iterations=30", "recon.init.num_points=300", "recon.densify.refine_stop_iter=0")


def test_conditions_are_the_assets_renders_and_the_rest_is_the_scene(tmp_path):
    src = make_lattice_dataset(tmp_path / "pool", num_train=1, num_test=1)
    done = reconstruct_pool(src, tmp_path / "rpool", recon="tiny", overrides=FAST)
    assert sorted(d["scene"] for d in done) == ["test_0", "train_0"]
    out = tmp_path / "rpool"
    assert json.loads((out / "splits.json").read_text()) == json.loads((src / "splits.json").read_text())
    scene = out / "train_0"
    assert (scene / DONE_FILE).is_file()
    gaussians, _ = read_asset_ply(scene / "asset" / "point_cloud.ply")
    rendered = render_lattice(gaussians, image_size=(32, 32)).rgb
    gt, pts = np.load(src / "train_0" / "gt_points.npz"), np.load(scene / "gt_points.npz")
    np.testing.assert_allclose(pts["rgb"], rendered[gt["view"], gt["pixel"][:, 0], gt["pixel"][:, 1]],
                               rtol=0, atol=1e-5)
    assert not np.allclose(pts["rgb"], gt["rgb"])       # the conditions did change
    for key in ("xyz", "albedo", "roughness", "metallic", "view", "pixel"):
        np.testing.assert_array_equal(pts[key], gt[key])  # the target did not
    np.testing.assert_allclose(read_view_file(scene / LATTICE_SPLIT / "005", "rgb.exr"), rendered[5], atol=1e-6)
    assert (scene / LATTICE_SPLIT / "005" / "depth.exr").is_symlink()
    info = json.loads((scene / "asset" / "recon.json").read_text())
    assert info["num_gaussians"] == gaussians.num_gaussians and info["config"]["iterations"] == 30
    assert info["train_split"] == LATTICE_SPLIT and info["pool_format"] == "gspi-reconstructed-pool"
    assert reconstruct_pool(src, out, recon="tiny", overrides=FAST) == []  # resumed: nothing left
    assert "| unclassed | 2 |" in summary_table(out)


def test_highlight_stats_and_psnr_golden():
    gt = np.zeros((1, 2, 2, 3), np.float32)
    gt[0, 0, 0] = 3.0
    gt[0, 0, 1] = 0.5
    asset = np.full_like(gt, 0.25)
    stats = highlight_stats(gt, asset)
    assert stats["gt_frac_above_1"] == 0.5 and stats["asset_frac_above_1"] == 0.0
    # clamped: errors 0.75, 0.25 on two pixels, 0.25 on two background pixels -> mse 0.1875
    assert abs(display_psnr(gt, asset) - 10 * np.log10(1 / 0.1875)) < 1e-5  # float32 images


def test_the_command_line_takes_overrides_before_or_after_its_options(monkeypatch, tmp_path):
    import gspi.recon.reconstructed_pool as rp

    calls = []
    monkeypatch.setattr(rp, "reconstruct_pool", lambda src, out, **kw: calls.append(kw))
    rp.main([str(tmp_path / "a"), str(tmp_path / "b"), "--recon", "tiny", "recon.iterations=1800"])
    rp.main([str(tmp_path / "a"), str(tmp_path / "b"), "recon.iterations=1800", "--recon", "tiny"])
    assert calls == [{"recon": "tiny", "workers": 1, "overrides": ("recon.iterations=1800",)}] * 2
