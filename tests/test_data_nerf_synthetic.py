"""NeRF-synthetic import/export round trip (gspi.data.layouts.nerf_synthetic)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from eval.common.colorspace import linear_to_srgb
from eval.common.layout import read_scene, read_view_file
from gspi.data.layouts.nerf_synthetic import (blender_c2w_to_opencv_w2c, export_nerf_synthetic,
                                      import_nerf_synthetic, intrinsics_from_angle_x,
                                      opencv_w2c_to_blender_c2w, write_rgba)
from tests.fixtures import generated_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return generated_scene(tmp_path_factory.mktemp("nerf") / "data", 16)


def test_camera_convention():
    w2c = np.eye(4)
    w2c[:3, 3] = [0.1, -0.2, 3.0]
    c2w_blender = opencv_w2c_to_blender_c2w(w2c)
    np.testing.assert_allclose(c2w_blender[:3, 1], [0, -1, 0])  # y up = -(OpenCV y down)
    np.testing.assert_allclose(c2w_blender[:3, 2], [0, 0, -1])  # z back = -(OpenCV forward)
    np.testing.assert_allclose(blender_c2w_to_opencv_w2c(c2w_blender), w2c, atol=1e-15)
    K = intrinsics_from_angle_x(2 * math.atan(0.5), 100, 60)
    np.testing.assert_allclose(K, [[100, 0, 50], [0, 100, 30], [0, 0, 1]], atol=1e-12)


def test_round_trip(scene, tmp_path):
    nerf = export_nerf_synthetic(scene.root, tmp_path / "nerf")
    meta = json.loads((nerf / "transforms_train.json").read_text())
    assert len(meta["frames"]) == 32 and meta["frames"][0]["file_path"] == "./train/000"
    back = import_nerf_synthetic(nerf, tmp_path / "canonical")
    again = read_scene(back.root)
    assert again.name == scene.name and (again.width, again.height) == (16, 16)
    assert again.capture_env == scene.capture_env and again.relight_envs == scene.relight_envs
    assert again.envmap_path(scene.capture_env).is_file()
    for split, views in scene.views.items():
        assert [v.id for v in again.views[split]] == [v.id for v in views]
        for v, w in zip(views, again.views[split]):
            np.testing.assert_allclose(w.K, v.K, atol=1e-6)
            np.testing.assert_allclose(w.w2c, v.w2c, atol=1e-6)
            a, b = scene.view_dir(split, v.id), again.view_dir(split, w.id)
            for name in ("mask.png", "albedo.png", "roughness.png", "metallic.png",
                         "normal.exr", "depth.exr"):
                assert np.array_equal(read_view_file(a, name), read_view_file(b, name)), name
            mask = read_view_file(a, "mask.png")[..., 0] > 0.5
            srgb = lambda x: linear_to_srgb(torch.from_numpy(x)).numpy()  # noqa: E731
            orig, imp = srgb(read_view_file(a, "rgb.exr")), srgb(read_view_file(b, "rgb.exr"))
            assert np.abs(orig - imp)[mask].max() <= 0.5 / 255 + 1e-6  # 8-bit quantisation
            assert (read_view_file(b, "rgb.exr")[~mask] == 0).all()


def test_white_background_and_missing_maps(tmp_path):
    rgba = np.zeros((4, 6, 4))
    rgba[1:3, 2:4] = [1.0, 0.5, 0.0, 1.0]
    write_rgba(tmp_path / "src" / "test" / "r_0.png", rgba)
    c2w = opencv_w2c_to_blender_c2w(np.eye(4)).tolist()
    (tmp_path / "src" / "transforms_test.json").write_text(json.dumps(
        {"camera_angle_x": 0.7, "frames": [{"file_path": "./test/r_0", "transform_matrix": c2w}]}))
    s = import_nerf_synthetic(tmp_path / "src", tmp_path / "out", composite="white")
    vdir = s.view_dir("test", "r_0")
    rgb = read_view_file(vdir, "rgb.exr")
    assert s.name == "src" and s.capture_env == "unknown"
    np.testing.assert_allclose(rgb[0, 0], [1, 1, 1])
    np.testing.assert_allclose(rgb[1, 2], [1.0, ((128 / 255 + 0.055) / 1.055) ** 2.4, 0.0], atol=1e-6)
    assert read_view_file(vdir, "mask.png").sum() == 4
    assert not (vdir / "albedo.png").exists()
