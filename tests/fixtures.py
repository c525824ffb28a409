"""A tiny ground-truth dataset built in code: analytic spheres in the canonical layout.

Used by the evaluation tests and by `make demo` until the pipeline exists. Each scene is a
unit-radius-0.8 sphere with procedural albedo/roughness/metallic seen by a few cameras; the
relit ground truth is not stored (the evaluator renders it from the maps).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eval.common.imageio import write_exr
from eval.common.layout import Scene, View, write_material, write_scene_json, write_view_file
from eval.common.atomic import write_json_atomic

RADIUS = 0.8


def look_at_w2c(center: np.ndarray, target=np.zeros(3), up=np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """OpenCV world-to-camera matrix of a camera at `center` looking at `target`."""
    f = target - center
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])  # rows: camera axes in world
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, -R @ center
    return w2c


def intrinsics(size: int, fov_deg: float = 40.0) -> np.ndarray:
    focal = size / (2.0 * np.tan(np.radians(fov_deg) / 2.0))
    return np.array([[focal, 0.0, size / 2.0], [0.0, focal, size / 2.0], [0.0, 0.0, 1.0]])


def render_sphere_maps(K: np.ndarray, w2c: np.ndarray, size: int, seed: int) -> dict:
    """Per-pixel ground truth of a sphere at the origin: maps, normal, depth, mask."""
    j, i = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="xy")
    dirs_cam = np.stack([j, i, np.ones_like(j)], -1) @ np.linalg.inv(K).T
    R, t = w2c[:3, :3], w2c[:3, 3]
    origin = -R.T @ t
    d = dirs_cam @ R
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ origin
    disc = b**2 - (origin @ origin - RADIUS**2)
    mask = disc > 0
    s = -b - np.sqrt(np.where(mask, disc, 0.0))
    p = origin + s[..., None] * d
    normal = np.where(mask[..., None], p / RADIUS, 0.0)
    depth = np.where(mask, (p - origin) @ R[2], 0.0)
    rng = np.random.default_rng(seed)
    hue = rng.uniform(0.2, 0.9, size=(2, 3))
    checker = ((np.floor(p[..., 0] * 4) + np.floor(p[..., 1] * 4) + np.floor(p[..., 2] * 4)) % 2)
    albedo = np.where(checker[..., None] > 0, hue[0], hue[1])
    roughness = 0.25 + 0.4 * (np.sin(p[..., 2] * 9.0) > 0)
    metallic = (p[..., 0] > 0.3).astype(np.float64)
    m3 = mask[..., None]
    return {"albedo": np.where(m3, albedo, 0.0), "roughness": np.where(mask, roughness, 0.0),
            "metallic": np.where(mask, metallic, 0.0), "normal": normal.astype(np.float32),
            "depth": depth.astype(np.float32), "mask": mask.astype(np.float64)}


def make_envmap(seed: int, height: int = 16, width: int = 32) -> np.ndarray:
    """A smooth HDR lat-long map with a bright lobe (linear radiance)."""
    rng = np.random.default_rng(seed)
    r, c = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    sky = 0.3 + 0.5 * (1 - r / height)[..., None] * rng.uniform(0.5, 1.0, 3)
    lobe = np.exp(-(((r - rng.integers(2, 6)) / 2.0) ** 2 + ((c - rng.integers(0, width)) / 3.0) ** 2))
    return (sky + 20.0 * lobe[..., None]).astype(np.float32)


def make_scene(root: Path, name: str, *, size: int = 48, seed: int = 0,
               num_train: int = 2, num_test: int = 3) -> Scene:
    K = intrinsics(size)
    views = {}
    for split, count, elev in (("train", num_train, 0.6), ("test", num_test, 0.3)):
        views[split] = []
        for k in range(count):
            az = 2 * np.pi * (k + 0.5 * (split == "test")) / count + 0.1 * seed
            center = 3.0 * np.array([np.cos(az) * np.cos(elev), np.sin(az) * np.cos(elev), np.sin(elev)])
            views[split].append(View(f"{k:03d}", split, K, look_at_w2c(center)))
    scene = Scene(root=root / name, name=name, width=size, height=size, views=views,
                  capture_env="cap", relight_envs=["env_a", "env_b"])
    write_scene_json(scene)
    for k, env in enumerate(("cap", "env_a", "env_b")):
        write_exr(scene.envmap_path(env), make_envmap(seed * 10 + k))
    for split, vs in views.items():
        for v in vs:
            maps = render_sphere_maps(v.K, v.w2c, size, seed)
            vdir = scene.view_dir(split, v.id)
            for channel in ("albedo", "roughness", "metallic"):
                write_material(vdir, channel, maps[channel])
            write_view_file(vdir, "normal.exr", maps["normal"])
            write_view_file(vdir, "depth.exr", maps["depth"])
            write_view_file(vdir, "mask.png", maps["mask"])
            rgb = (maps["albedo"] ** 2.2 * 0.8).astype(np.float32)  # a stand-in input image
            write_view_file(vdir, "rgb.exr", rgb)
            write_view_file(vdir, "rgb.png", rgb ** (1 / 2.2))
    return scene


def make_dataset(root: str | Path, *, num_scenes: int = 2, size: int = 48) -> Path:
    """`num_scenes` sphere scenes + splits.json (all scenes in `test`)."""
    root = Path(root)
    names = [f"sphere_{k}" for k in range(num_scenes)]
    for k, name in enumerate(names):
        make_scene(root, name, size=size, seed=k)
    write_json_atomic(root / "splits.json", {"train": [], "val": [], "test": names})
    return root


def generated_scene(out: Path, image_size: int) -> Scene:
    """One procedural scene made by gspi-data's generator (seed 3, 1 train scene, 2 test views,
    1 relight environment, no extras) written to `out`, read back."""
    from eval.common.layout import read_scene, read_splits
    from gspi.data.generate import BenchmarkConfig, generate_dataset

    cfg = BenchmarkConfig(num_train_scenes=1, num_val_scenes=0, num_test_scenes=0, image_size=image_size,
                          supersample=1, env_height=16, num_test_views=2, num_val_views=0,
                          num_relight_envs=1, point_clouds=False, contact_sheets=False)
    generate_dataset(out, cfg, seed=3)
    return read_scene(out / read_splits(out)["train"][0])


def preset(name: str, *overrides: str):
    """The protocol of preset conf/eval/<name>.yaml with Hydra overrides, validated as at start-up."""
    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR

    from eval.config import register_configs, validate_protocol

    register_configs()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="gspi_eval", overrides=[f"eval={name}", "gt=g", "pred=p",
                                                            "out=o", *overrides])
    validate_protocol(cfg.eval)
    return cfg.eval


def protocol(**overrides):
    """The default evaluation protocol with dotted-key overrides, validated as at start-up."""
    from omegaconf import OmegaConf

    from eval.config import ProtocolConfig, validate_protocol

    cfg = OmegaConf.structured(ProtocolConfig)
    for key, value in overrides.items():
        OmegaConf.update(cfg, key, value)
    validate_protocol(cfg)
    return cfg


def make_prediction(gt_root: str | Path, pred_root: str | Path, *, method: str = "perturbed",
                    roughness_offset: float = 6554 / 65535, albedo_scale: float = 1.0,
                    channels=("albedo", "roughness", "metallic"), split: str = "test") -> Path:
    """A prediction folder derived from the ground truth with known, controlled errors, for
    the views of `split` (test, or train: the lattice views).

    roughness: gt + offset inside the mask (exactly representable in 16 bits);
    albedo: linear albedo times `albedo_scale`; metallic: copied.
    """
    from eval.common.colorspace import linear_to_srgb, srgb_to_linear
    from eval.common.layout import read_scene, read_view_file, write_meta
    import torch

    gt_root, pred_root = Path(gt_root), Path(pred_root)
    for scene_json in sorted(gt_root.glob("*/scene.json")):
        scene = read_scene(scene_json.parent)
        for v in scene.split_views(split):
            src, dst = scene.view_dir(split, v.id), pred_root / scene.name / split / v.id
            mask = read_view_file(src, "mask.png")[..., 0] > 0.5
            if "albedo" in channels:
                a = torch.from_numpy(read_view_file(src, "albedo.png")).double()
                a = linear_to_srgb(srgb_to_linear(a) * albedo_scale).numpy()
                write_material(dst, "albedo", a)
            if "roughness" in channels:
                r = read_view_file(src, "roughness.png")
                write_material(dst, "roughness", np.where(mask[..., None], r + roughness_offset, r))
            if "metallic" in channels:
                write_material(dst, "metallic", read_view_file(src, "metallic.png"))
        write_meta(pred_root / scene.name, method=method, material_s=60.0, end_to_end_s=120.0)
    return pred_root


def main(argv: list[str] | None = None) -> None:
    """`python -m tests.fixtures OUT`: OUT/gt (2 sphere scenes) and two predictions under OUT."""
    import argparse

    parser = argparse.ArgumentParser(description="Two analytic sphere scenes (gt/) and two predictions.")
    parser.add_argument("out", type=Path, help="folder to write OUT/gt and OUT/pred_* into")
    out = parser.parse_args(argv).out
    gt = make_dataset(out / "gt", num_scenes=2, size=64)
    make_prediction(gt, out / "pred_roughness_offset", method="roughness+0.1")
    make_prediction(gt, out / "pred_albedo_only", method="albedo-only x0.8",
                    channels=("albedo",), albedo_scale=0.8)
    print(f"wrote {gt} and predictions under {out}")


if __name__ == "__main__":
    main()


def surfel_sphere(num: int = 3000, *, radius: float = 0.8, color=(0.6, 0.4, 0.2),
                  opacity: float = 0.98, floaters: int = 0, seed: int = 0):
    """A 2DGS asset: surfels tangent to a sphere (Fibonacci points), plus optional floaters.

    Floaters are random surfels at radius 1.1-1.5 facing random directions, the kind of
    free-space clutter Stage I's filters must remove.
    """
    import math

    import torch

    from gspi.gaussians.model import Gaussians2D
    from gspi.gaussians.sh import rgb_to_sh

    g = torch.Generator().manual_seed(seed)
    k = torch.arange(num, dtype=torch.float64) + 0.5
    z = 1 - 2 * k / num
    phi = k * math.pi * (3 - math.sqrt(5))
    normals = torch.stack([torch.sqrt(1 - z * z) * torch.cos(phi),
                           torch.sqrt(1 - z * z) * torch.sin(phi), z], -1)
    means = radius * normals
    spacing = radius * math.sqrt(4 * math.pi / num)
    scales = torch.full((num, 2), 0.6 * spacing, dtype=torch.float64)
    if floaters:
        d = torch.nn.functional.normalize(torch.randn(floaters, 3, generator=g, dtype=torch.float64), dim=-1)
        r = 1.1 + 0.4 * torch.rand(floaters, 1, generator=g, dtype=torch.float64)
        means = torch.cat([means, d * r])
        normals = torch.cat([normals, torch.nn.functional.normalize(
            torch.randn(floaters, 3, generator=g, dtype=torch.float64), dim=-1)])
        scales = torch.cat([scales, torch.full((floaters, 2), 1.5 * spacing, dtype=torch.float64)])
    zaxis = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(normals)
    quats = torch.cat([1 + (normals * zaxis).sum(-1, keepdim=True),
                       torch.cross(zaxis, normals, dim=-1)], -1)
    quats = torch.nn.functional.normalize(quats, dim=-1)  # rotates +z onto the normal
    n = len(means)
    dc = rgb_to_sh(torch.tensor(color, dtype=torch.float64)).expand(n, 1, 3)
    return Gaussians2D(means=means.float(), quats=quats.float(), log_scales=scales.log().float(),
                       opacity_logits=torch.full((n,), math.log(opacity / (1 - opacity))),
                       sh_dc=dc.float().clone(), sh_rest=torch.zeros(n, 0, 3))


def random_gaussians(n: int, degree: int, pbr: bool, seed: int = 0):
    """A ``Gaussians2D`` of n surfels, every attribute drawn from N(0, 1) (logits, log scales, SH
    of ``degree``; PBR logits if ``pbr``)."""
    import torch

    from gspi.gaussians.model import Gaussians2D

    gen = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2
    extra = {}
    if pbr:
        extra = {
            "albedo_logits": torch.randn(n, 3, generator=gen),
            "roughness_logits": torch.randn(n, 1, generator=gen),
            "metallic_logits": torch.randn(n, 1, generator=gen),
        }
    return Gaussians2D(
        means=torch.randn(n, 3, generator=gen), quats=torch.randn(n, 4, generator=gen),
        log_scales=torch.randn(n, 2, generator=gen), opacity_logits=torch.randn(n, generator=gen),
        sh_dc=torch.randn(n, 1, 3, generator=gen), sh_rest=torch.randn(n, k - 1, 3, generator=gen), **extra,
    )
