"""The light read-out's table kept between processes (gspi/stage2/light_table_cache.py): a second
process reads the first's table instead of reading the scene again, and anything the table is a
function of (the config, the light told, an input file) is a miss, as is a damaged file."""
from __future__ import annotations

import logging
import os

import numpy as np
import pytest

from gspi.stage2 import light_condition, light_table_cache
from gspi.stage2.data import PointDataConfig, load_scene_points, local_condition
from tests.stage2_fixtures import make_lattice_scene

ENV = "studio_rgb"
LIGHT = PointDataConfig(light_readout=True, light_env_height=32)


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return make_lattice_scene(tmp_path_factory.mktemp("cached"), "lit_sphere", seed=2, lit=ENV)


def read(root, cache, cfg=LIGHT, told="estimated"):
    """A fresh process's view of the scene: (condition rows, light info)."""
    scene = load_scene_points(root, None)
    scene.light_cache, scene.told_light = cache, told
    rows = local_condition(scene, np.arange(scene.num_points), scene.xyz, "top_rgb_onehot", light=cfg)
    return rows, scene.light_info


def no_reading(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the scene was read again")
    monkeypatch.setattr(light_condition, "readout_table", refuse)


def test_a_second_process_reads_the_first_ones_table(root, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    first, info = read(root, cache)
    files = list(cache.glob("lit_sphere/light-*.npz"))
    assert len(files) == 1
    no_reading(monkeypatch)
    second, second_info = read(root, cache)
    np.testing.assert_array_equal(second, first)
    assert second_info == info == {"env": ENV, "rotation_deg": 0.0, "wrong": False}


def test_without_a_cache_nothing_is_written_and_the_rows_are_the_same(root, tmp_path):
    cached, _ = read(root, tmp_path / "cache")
    plain, _ = read(root, None)
    np.testing.assert_array_equal(plain, cached)
    assert not any(tmp_path.glob("*.npz"))


def test_a_changed_config_or_told_light_is_a_miss(root, tmp_path):
    cache = tmp_path / "cache"
    read(root, cache)
    read(root, cache, cfg=PointDataConfig(light_readout=True, light_env_height=32, light_normal_profile=3))
    assert len(list(cache.glob("lit_sphere/light-*.npz"))) == 2
    key = light_table_cache.table_key
    assert key(LIGHT, "capture", "estimated", "s", [root]) != key(LIGHT, "estimated", "estimated", "s", [root])
    assert key(LIGHT, "estimated", "estimated", "s", [root]) != key(LIGHT, "estimated", "turned90", "s", [root])
    assert key(LIGHT, "capture", "estimated", "s", [root]) == key(LIGHT, "capture", "estimated", "s", [root, root])


def test_a_changed_input_file_is_a_miss(root, tmp_path):
    cache = tmp_path / "cache"
    before = light_table_cache.table_key(LIGHT, "capture", "estimated", "lit_sphere", [root])
    read(root, cache)
    rgb = next(root.glob("train/*/rgb.exr"))
    stat = rgb.stat()
    os.utime(rgb, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    try:
        assert light_table_cache.table_key(LIGHT, "capture", "estimated", "lit_sphere", [root]) != before
        read(root, cache)
        assert len(list(cache.glob("lit_sphere/light-*.npz"))) == 2
    finally:
        os.utime(rgb, ns=(stat.st_atime_ns, stat.st_mtime_ns))


def test_a_damaged_file_is_read_again_and_rewritten(root, tmp_path, caplog):
    cache = tmp_path / "cache"
    first, _ = read(root, cache)
    (path,) = cache.glob("lit_sphere/light-*.npz")
    path.write_bytes(b"not an npz")
    with caplog.at_level(logging.WARNING, logger="gspi.stage2.light_table_cache"):
        again, _ = read(root, cache)
    assert "unreadable light read-out cache" in caplog.text and str(path) in caplog.text
    np.testing.assert_array_equal(again, first)
    assert light_table_cache.load_table(path) is not None


def test_a_malformed_table_is_a_miss(tmp_path, caplog):
    path = tmp_path / "light-x.npz"
    light_table_cache.save_table(path, (np.zeros((4, 3)), np.zeros((3, 7))), {"env": ENV})
    with caplog.at_level(logging.WARNING, logger="gspi.stage2.light_table_cache"):
        assert light_table_cache.load_table(path) is None
    assert "malformed" in caplog.text
    light_table_cache.save_table(path, (np.zeros((4, 3)), np.ones((4, 7))), {"env": ENV, "wrong": np.bool_(True)})
    (xyz, rows), info = light_table_cache.load_table(path)
    assert rows.shape == (4, 7) and info == {"env": ENV, "wrong": True}
