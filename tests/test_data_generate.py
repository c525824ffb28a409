"""End-to-end checks of the procedural benchmark (gspi-data, `tiny` preset at reduced sizes)."""
from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from eval.common.imageio import read_exr
from eval.common.layout import GT_VIEW_FILES, read_scene, read_splits, read_view_file
from eval.common.argv import apply_aliases
from gspi.cli.data import run
from gspi.data.lattice import lattice_cameras
from gspi.data.procedural.render_scene import relight_stored_view
from gspi.data.procedural.sdf_shapes import ShapeSDF
from tests.data_config import compose_data_config

REPO = Path(__file__).resolve().parents[1]
# The tiny preset shrunk further so that the whole module runs in seconds.
SMALL = ["data.num_train_scenes=2", "data.num_val_scenes=0", "data.num_test_scenes=1",
         "data.image_size=32", "data.supersample=2", "data.env_height=16",
         "data.num_test_views=2", "data.num_val_views=1", "data.num_relight_envs=2"]


def make_config(out: Path, seed: int = 0, extra: list[str] | None = None):
    return compose_data_config("tiny", out, seed, [*SMALL, *(extra or [])])


def file_hashes(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("gspi_data") / "tiny"
    return out, run(make_config(out))


def scenes(out: Path) -> list:
    return [read_scene(out / n) for names in read_splits(out).values() for n in names]


def test_splits_cover_every_scene_once(dataset):
    out, result = dataset
    splits = read_splits(out)
    assert set(splits) == {"train", "val", "test"}
    assert [len(splits[s]) for s in ("train", "val", "test")] == [2, 0, 1]
    names = sum(splits.values(), [])
    assert len(names) == len(set(names)) == 3
    assert sorted(p.name for p in out.iterdir() if (p / "scene.json").is_file()) == sorted(names)
    assert result["mode"] == "generate" and len(result["scenes"]) == 3


def test_every_scene_reads_and_has_the_canonical_views(dataset):
    out, _ = dataset
    K, w2c = lattice_cameras(width=32, height=32)
    for scene in scenes(out):
        assert (scene.width, scene.height) == (32, 32)
        assert [v.id for v in scene.views["train"]] == [f"{k:03d}" for k in range(32)]
        assert np.allclose(np.stack([v.w2c for v in scene.views["train"]]), w2c, atol=1e-12)
        assert len(scene.views["test"]) == 2 and len(scene.views["val"]) == 1
        assert len(scene.relight_envs) == 2 and scene.capture_env not in scene.relight_envs
        for env in [scene.capture_env, *scene.relight_envs]:
            env_map = read_exr(scene.envmap_path(env))
            assert env_map.shape == (16, 32, 3) and env_map.min() >= 0
        for split, views in scene.views.items():
            for v in views:
                for name in GT_VIEW_FILES:
                    assert (scene.view_dir(split, v.id) / name).is_file(), (split, v.id, name)
        assert (scene.root / "contact_sheet.png").is_file()


def test_value_ranges(dataset):
    out, _ = dataset
    for scene in scenes(out):
        for split, views in scene.views.items():
            for v in views:
                f = {n: read_view_file(scene.view_dir(split, v.id), n) for n in GT_VIEW_FILES}
                mask = f["mask.png"][..., 0]
                assert set(np.unique(mask)) <= {0.0, 1.0}
                inside = mask > 0.5
                assert inside.sum() > 20
                for name in ("albedo.png", "roughness.png", "metallic.png"):
                    assert f[name].min() >= 0 and f[name].max() <= 1
                    assert (f[name][~inside] == 0).all()
                norms = np.linalg.norm(f["normal.exr"], axis=-1)
                np.testing.assert_allclose(norms[inside], 1.0, atol=1e-5)
                assert (norms[~inside] == 0).all()
                assert (f["depth.exr"][..., 0][inside] > 0).all()
                assert (f["depth.exr"][..., 0][~inside] == 0).all()
                assert f["rgb.exr"].min() >= 0 and np.isfinite(f["rgb.exr"]).all()
                assert f["rgb.exr"][inside].mean() > 0.01  # exposure: not black


def test_relit_ground_truth_is_reproduced_bit_exactly_from_the_files(dataset):
    out, _ = dataset
    for scene in scenes(out):
        for v in scene.views["test"]:
            for env in scene.relight_envs:
                stored = read_exr(scene.view_dir("test", v.id) / f"relit_{env}.exr")
                env_map = torch.from_numpy(read_exr(scene.envmap_path(env)))
                again = relight_stored_view(scene, v, env_map)
                assert np.array_equal(stored, again)
                assert stored.max() > 0


def test_gt_point_cloud_lies_on_the_sdf_surface(dataset):
    out, _ = dataset
    footprint = 2 * 3.0 * math.tan(math.radians(22.5)) / 32  # one pixel at the origin, 32 px
    for scene in scenes(out):
        pts = np.load(scene.root / "gt_points.npz")
        n = len(pts["xyz"])
        assert pts["xyz"].shape == (n, 3) and pts["pixel"].shape == (n, 2)
        for key in ("view", "roughness", "metallic"):
            assert pts[key].shape == (n,)
        assert set(np.unique(pts["view"])) <= set(range(32))
        masks = sum(int((read_view_file(scene.view_dir("train", v.id), "mask.png") > 0.5).sum())
                    for v in scene.views["train"])
        assert n == masks
        dist = ShapeSDF(scene.extra["generator"]["shape"])(torch.from_numpy(pts["xyz"])).abs().numpy()
        assert np.quantile(dist, 0.95) < 1e-4   # pixel-centre hits: exact depth
        assert dist.max() < footprint           # silhouette pixels: within a pixel footprint
        k = 5  # a point's attributes are its source pixel's stored values
        v, (r, c) = pts["view"][k], pts["pixel"][k]
        vdir = scene.view_dir("train", f"{v:03d}")
        np.testing.assert_array_equal(pts["albedo"][k], read_view_file(vdir, "albedo.png")[r, c])
        np.testing.assert_array_equal(pts["rgb"][k], read_view_file(vdir, "rgb.exr")[r, c])


def test_same_seed_gives_identical_files(dataset, tmp_path):
    out, _ = dataset
    again = tmp_path / "again"
    run(make_config(again))
    a, b = file_hashes(out), file_hashes(again)
    assert a.keys() == b.keys()
    assert a == b


def test_device_auto_is_the_cpu_here_byte_for_byte(dataset, tmp_path):
    """gspi-data device=auto on a machine without CUDA: the files of the default (device=cpu)."""
    if torch.cuda.is_available():
        pytest.skip("CUDA is present: auto renders there (not byte-identical to the CPU)")
    out, _ = dataset
    again = tmp_path / "auto"
    assert run(make_config(again, extra=["device=auto"]))["device"] == "cpu"
    assert file_hashes(again) == file_hashes(out)


def test_other_seed_gives_other_scenes(tmp_path):
    from gspi.data.generate import scene_recipes
    from gspi.cli.data import benchmark_config

    r0 = scene_recipes(0, benchmark_config(make_config(tmp_path)))
    r1 = scene_recipes(1, benchmark_config(make_config(tmp_path, seed=1)))
    assert [r["shape"] for r in r0] != [r["shape"] for r in r1]


def test_preset_alias():
    assert apply_aliases(["preset=tiny", "out=x", "seed=0"], "gspi_data") == ["data=tiny", "out=x", "seed=0"]


def test_command_line_records_its_config_inside_out(tmp_path):
    out = tmp_path / "cli"
    cmd = [sys.executable, "-m", "gspi.cli.data", "preset=tiny", f"out={out}", "seed=0",
           "data.num_train_scenes=1", "data.num_val_scenes=0", "data.num_test_scenes=0",
           "data.image_size=8", "data.supersample=1", "data.env_height=16",
           "data.num_test_views=0", "data.num_val_views=0", "data.num_relight_envs=0",
           "data.contact_sheets=false"]
    subprocess.run(cmd, cwd=tmp_path, check=True, capture_output=True,
                   env={**os.environ, "PYTHONPATH": str(REPO)})
    assert (out / ".hydra" / "config.yaml").is_file()
    assert "data.image_size=8" in (out / ".hydra" / "overrides.yaml").read_text()
    assert read_splits(out)["train"] and not (tmp_path / "outputs").exists()


def test_a_progress_line_per_scene_and_the_same_files(dataset, tmp_path, caplog):
    """gspi-data logs "scene k/N: <name> ..." as each scene finishes; the files are unchanged."""
    import logging

    out, result = dataset
    caplog.set_level(logging.INFO, logger="gspi.data.generate")
    again = run(make_config(tmp_path / "again"))
    names = [s["name"] for s in again["scenes"]]
    lines = [r.getMessage() for r in caplog.records if r.name == "gspi.data.generate"]
    assert [line.split(" in ")[0] for line in lines] == \
        [f"scene {k}/{len(names)}: {n}" for k, n in enumerate(names, 1)], lines
    assert file_hashes(tmp_path / "again") == file_hashes(out)
