"""The canonical V = 32 Fibonacci hemisphere lattice and its cameras (gspi.data.lattice)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gspi.data.lattice import (GOLDEN_ANGLE, fibonacci_hemisphere_lattice, held_out_directions,
                               intrinsics_from_fov, lattice_cameras, look_at_w2c,
                               nearest_neighbour_angles)
from gspi.data.procedural.render_scene import scene_views

# Near-uniform spacing: for V = 32 the nearest-neighbour angles span 22.3..24.7 deg (ratio 1.11).
MAX_NN_RATIO = 1.25


class TestFibonacciHemisphereLattice:
    def test_unit_upper_hemisphere(self):
        d = fibonacci_hemisphere_lattice(32)
        assert d.shape == (32, 3)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        assert (d[:, 2] > 0).all()

    def test_closed_form(self):
        d = fibonacci_hemisphere_lattice(32)
        i = np.arange(32)
        np.testing.assert_allclose(d[:, 2], 1 - (i + 0.5) / 32, atol=1e-15)
        np.testing.assert_allclose(np.arctan2(d[:, 1], d[:, 0]),
                                   np.angle(np.exp(1j * i * GOLDEN_ANGLE)), atol=1e-12)
        assert math.isclose(GOLDEN_ANGLE, math.pi * (3 - math.sqrt(5)))

    def test_equal_area_in_z(self):
        z = fibonacci_hemisphere_lattice(32)[:, 2]
        np.testing.assert_allclose(np.diff(z), -1 / 32, atol=1e-12)

    def test_near_uniform_spacing(self):
        nn = nearest_neighbour_angles(fibonacci_hemisphere_lattice(32))
        assert nn.max() / nn.min() < MAX_NN_RATIO
        assert math.degrees(nn.min()) > 20.0

    def test_deterministic(self):
        assert np.array_equal(fibonacci_hemisphere_lattice(32), fibonacci_hemisphere_lattice(32))

    def test_min_elevation(self):
        d = fibonacci_hemisphere_lattice(32, min_elevation_deg=15.0)
        assert d[:, 2].min() > math.sin(math.radians(15.0))

    @pytest.mark.parametrize("bad", [{"num_views": 0}, {"min_elevation_deg": 90.0}])
    def test_rejects_bad_arguments(self, bad):
        with pytest.raises(ValueError):
            fibonacci_hemisphere_lattice(**{"num_views": 32, **bad})


class TestLatticeCameras:
    def test_pose_and_intrinsics(self):
        K, w2c = lattice_cameras(radius=3.0, fov_deg=45.0, width=64, height=48)
        d = fibonacci_hemisphere_lattice(32)
        assert K.shape == (32, 3, 3) and w2c.shape == (32, 4, 4)
        for k in range(32):
            R, t = w2c[k, :3, :3], w2c[k, :3, 3]
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(R) == pytest.approx(1.0)
            np.testing.assert_allclose(-R.T @ t, 3.0 * d[k], atol=1e-12)   # camera centre
            origin_cam = w2c[k] @ np.array([0.0, 0.0, 0.0, 1.0])
            uv = K[k] @ origin_cam[:3]
            np.testing.assert_allclose(uv[:2] / uv[2], [32.0, 24.0], atol=1e-9)  # looks at 0
            up = w2c[k, :3, :3] @ np.array([0.0, 0.0, 1.0])
            assert up[1] < 0  # OpenCV y points down: world up maps to -y
        assert K[0, 0, 0] == pytest.approx(32.0 / math.tan(math.radians(22.5)))

    def test_look_at_rejects_parallel_up(self):
        with pytest.raises(ValueError):
            look_at_w2c(np.array([0.0, 0.0, 3.0]))

    def test_intrinsics(self):
        K = intrinsics_from_fov(90.0, 100, 80)
        np.testing.assert_allclose(K, [[50, 0, 50], [0, 50, 40], [0, 0, 1]], atol=1e-12)

    def test_view_index_binds_the_same_camera_in_every_scene(self):
        """Stage II's one-hot index k <-> train view k: identical for any two scenes."""
        lattice = {"num_views": 32, "radius": 3.0, "fov_deg": 45.0, "min_elevation_deg": 0.0}
        rng = np.random.default_rng(0)
        recipes = [{"test_directions": held_out_directions(3, rng, lattice=np.zeros((0, 3))).tolist(),
                    "val_directions": []} for _ in range(2)]
        a, b = (scene_views(r, width=32, height=32, lattice=lattice) for r in recipes)
        K, w2c = lattice_cameras(width=32, height=32)
        assert [v.id for v in a["train"]] == [f"{k:03d}" for k in range(32)]
        for k, (va, vb) in enumerate(zip(a["train"], b["train"])):
            assert va.id == vb.id
            assert np.array_equal(va.w2c, vb.w2c) and np.array_equal(va.K, vb.K)
            assert np.array_equal(va.w2c, w2c[k]) and np.array_equal(va.K, K[k])
        assert not np.array_equal(a["test"][0].w2c, b["test"][0].w2c)  # held-out views vary


def test_held_out_directions_stay_off_the_lattice():
    lattice = fibonacci_hemisphere_lattice(32)
    d = held_out_directions(8, np.random.default_rng(3), lattice=lattice, min_separation_deg=6.0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert (d[:, 2] > 0).all()
    closest = np.degrees(np.arccos(np.clip((d @ lattice.T).max(axis=1), -1, 1)))
    assert closest.min() >= 6.0


def test_every_lattice_default_is_the_canonical_one():
    """CANONICAL_LATTICE is the one definition; the configs and dataclasses that repeat it agree."""
    from omegaconf import OmegaConf

    from gspi.data.generate import BenchmarkConfig
    from gspi.data.lattice import CANONICAL_LATTICE, NUM_LATTICE_VIEWS
    from gspi.stage1.config import Stage1Config

    conf = Path(__file__).resolve().parents[1] / "conf"
    assert dict(OmegaConf.load(conf / "gspi_data.yaml").lattice) == dict(CANONICAL_LATTICE)
    for name in ("default", "tiny", "paper"):
        stage1 = OmegaConf.load(conf / "stage1" / f"{name}.yaml")
        for key, value in CANONICAL_LATTICE.items():
            assert stage1.get(key, value) == value, (name, key)
    assert Stage1Config().lattice == dict(CANONICAL_LATTICE)
    assert BenchmarkConfig().lattice == dict(CANONICAL_LATTICE)
    assert NUM_LATTICE_VIEWS == CANONICAL_LATTICE["num_views"] == 32
    K, w2c = lattice_cameras(width=16, height=16)
    K2, w2c2 = lattice_cameras(width=16, height=16, **CANONICAL_LATTICE)
    assert np.array_equal(K, K2) and np.array_equal(w2c, w2c2)
