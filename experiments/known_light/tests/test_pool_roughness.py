import numpy as np
import pytest

from experiments.known_light import pool_roughness as pr


def write_scene(folder, roughness, metallic):
    folder.mkdir(parents=True)
    np.savez(folder / "gt_points.npz", roughness=np.asarray(roughness, np.float32),
             metallic=np.asarray(metallic, np.float32))


def test_scene_means_and_pooled_points_differ_as_they_should(tmp_path):
    # scene a: dielectric r 0.2, 0.8 (one matte of two), one metal point; scene b: four dielectric 0.9 (all matte)
    write_scene(tmp_path / "a", [0.2, 0.8, 0.1], [0.0, 0.0, 1.0])
    write_scene(tmp_path / "b", [0.9] * 4, [0.0] * 4)
    summary = pr.pool_roughness(tmp_path)
    assert summary["scenes"] == 2
    assert summary["dielectric_mean_roughness"] == pytest.approx((0.5 + 0.9) / 2, abs=1e-4)
    assert summary["dielectric_matte_share"] == pytest.approx((0.5 + 1.0) / 2, abs=1e-4)
    assert summary["metal_share"] == pytest.approx((1 / 3 + 0) / 2, abs=1e-4)
    assert summary["pooled_dielectric_mean_roughness"] == pytest.approx((0.2 + 0.8 + 3.6) / 6, abs=1e-4)
    assert summary["pooled_dielectric_matte_share"] == pytest.approx(5 / 6, abs=1e-4)


def test_an_all_metal_scene_is_left_out_of_the_dielectric_means(tmp_path):
    write_scene(tmp_path / "a", [0.3, 0.3], [1.0, 1.0])
    write_scene(tmp_path / "b", [0.6, 0.8], [0.0, 0.0])
    summary = pr.pool_roughness(tmp_path)
    assert summary["dielectric_mean_roughness"] == pytest.approx(0.7, abs=1e-4)
    assert summary["metal_share"] == pytest.approx(0.5, abs=1e-4)


def test_a_folder_without_scenes_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=str(tmp_path)):
        pr.pool_roughness(tmp_path)
