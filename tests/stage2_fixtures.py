"""Stage II's test data built in code: lattice sphere scenes and datasets, and the tiny gspi-train
config.

A lattice scene is an analytic sphere (tests/fixtures.py) whose train split is the canonical
32-view lattice, with its gt_points.npz; a lattice dataset is a few of them with splits.json.
The pytest fixture ``dataset`` (module scope) is defined here as ``lattice_dataset``: a test module
that wants it imports ``lattice_dataset`` explicitly and builds its own, as
tests/test_stage2_train.py and tests/test_stage2_validate.py do.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from eval.common.conf import CONF_DIR

SIZE = 32  # px: the smallest size eval.metrics' LPIPS accepts


def make_lattice_scene(root: Path, name: str, *, size: int = SIZE, seed: int = 0, lit: str | None = None) -> Path:
    """A sphere scene whose train split is the canonical 32-view lattice, with gt_points.npz.
    ``lit``: a procedural capture environment: the views are shaded under it by the split-sum
    shader (``envmaps/<lit>.exr`` and ``normal.exr`` written), as a generated scene's are."""
    from eval.common.layout import Scene, View, write_material, write_scene_json, write_view_file
    from gspi.data.lattice import lattice_cameras
    from gspi.data.point_clouds import write_scene_point_cloud
    from tests.fixtures import render_sphere_maps

    K, w2c = lattice_cameras(num_views=32, radius=3.0, fov_deg=45.0, width=size, height=size)
    views = {"train": [View(f"{k:03d}", "train", K[k], w2c[k]) for k in range(32)]}
    scene = Scene(root=root / name, name=name, width=size, height=size, views=views,
                  capture_env=lit or "cap", relight_envs=[])
    write_scene_json(scene)
    env = None
    if lit:
        from eval.common.imageio import write_exr
        from gspi.data.environments import make_environment

        env = make_environment(lit, 32, supersample=1)
        (scene.root / "envmaps").mkdir(parents=True, exist_ok=True)
        write_exr(scene.envmap_path(lit), env.numpy())
    for v in views["train"]:
        maps = render_sphere_maps(v.K, v.w2c, size, seed)
        vdir = scene.view_dir("train", v.id)
        for channel in ("albedo", "roughness", "metallic"):
            write_material(vdir, channel, maps[channel])
        write_view_file(vdir, "depth.exr", maps["depth"])
        write_view_file(vdir, "mask.png", maps["mask"])
        write_view_file(vdir, "rgb.exr", (maps["albedo"] ** 2.2 * 0.8).astype(np.float32) if env is None
                        else shade_sphere(maps, v.w2c, env))
        if env is not None:
            write_view_file(vdir, "normal.exr", maps["normal"])
    write_scene_point_cloud(scene)
    return scene.root


def shade_sphere(maps: dict, w2c: np.ndarray, env) -> np.ndarray:
    """[H, W, 3] linear radiance of the sphere's GT maps under ``env`` (eval.relight.split_sum)."""
    import torch

    from eval.common.colorspace import srgb_to_linear
    from eval.relight import split_sum

    mask = maps["mask"] > 0
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    h, w = mask.shape
    # the surface point of each pixel: along the normal from the origin (the sphere is centred there)
    from tests.fixtures import RADIUS
    point = maps["normal"].astype(np.float64) * RADIUS
    view = centre - point
    view /= np.maximum(np.linalg.norm(view, axis=-1, keepdims=True), 1e-9)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a[mask], dtype=np.float32))  # noqa: E731
    albedo = srgb_to_linear(t(maps["albedo"]))
    rgb = split_sum(albedo, t(maps["roughness"][..., None]), t(maps["metallic"][..., None]),
                    t(maps["normal"]), t(view), env).numpy()
    out = np.zeros((h, w, 3), dtype=np.float32)
    out[mask] = rgb
    return out


def make_lattice_dataset(root: Path, *, num_train: int = 2, num_test: int = 1) -> Path:
    from eval.common.atomic import write_json_atomic

    names = {"train": [f"train_{k}" for k in range(num_train)], "test": [f"test_{k}" for k in range(num_test)]}
    for k, name in enumerate(names["train"] + names["test"]):
        make_lattice_scene(root, name, seed=k)
    write_json_atomic(root / "splits.json", {**names, "val": []})
    return root


@pytest.fixture(scope="module", name="dataset")
def lattice_dataset(tmp_path_factory) -> Path:
    """The fixture ``dataset``: 2 train + 1 test lattice scenes, built once per test module that
    imports it (imported as ``lattice_dataset``, so the tests' ``dataset`` argument shadows no name)."""
    return make_lattice_dataset(tmp_path_factory.mktemp("s2train"), num_train=2, num_test=1)


def compose_cfg(overrides: list[str]):
    with initialize_config_dir(version_base="1.3", config_dir=CONF_DIR):
        return compose(config_name="gspi_train", overrides=overrides)


def tiny_cfg(dataset: Path, out: Path, *extra: str) -> dict:
    cfg = compose_cfg([f"data_dir={dataset}", f"out={out}", "stage2=tiny",
                       "stage2.prior.alexnet.input_size=64", *extra])
    return OmegaConf.to_container(cfg, resolve=True)


def gt_views_as_renders(root):
    """The scene's 32 lattice views in the form Stage I renders them (alpha = the GT mask): a
    ``LatticeRenders`` whose conditions must equal the training path's (condition parity)."""
    from eval.common.layout import read_scene, read_view_file
    from gspi.gaussians.lattice_render import LatticeRenders

    scene = read_scene(root)
    views = scene.split_views("train")
    dirs = [scene.view_dir("train", v.id) for v in views]
    return LatticeRenders(rgb=np.stack([read_view_file(d, "rgb.exr") for d in dirs]).astype(np.float32),
                          alpha=np.stack([read_view_file(d, "mask.png")[..., 0] for d in dirs]).astype(np.float32),
                          depth=np.stack([read_view_file(d, "depth.exr")[..., 0] for d in dirs]).astype(np.float32),
                          K=np.stack([v.K for v in views]), w2c=np.stack([v.w2c for v in views]))
