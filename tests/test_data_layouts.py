"""Readers and writers of the field's layouts (gspi/data/layouts/): each layout is written by
the test as its project's loader reads it (tiny fixtures), imported and checked; a generated
scene goes canonical -> export.format=<layout> -> import and must come back; bad folders fail
with one line naming the file; gspi-eval scores an imported scene and reports what the ground
truth lacks as absent."""
from __future__ import annotations

import json
import math
import pickle

import numpy as np
import pytest
import torch

from eval.common.colorspace import srgb_to_linear
from eval.envmap import latlong_directions
from eval.evaluate import evaluate
from eval.common.imageio import read_exr, read_png, write_exr, write_png
from eval.common.layout import LayoutError, read_view_file
from gspi.data.layouts import detect_format
from gspi.data.layouts.nero_glossy import export_nero_glossy, import_nero_glossy
from gspi.data.layouts.orb_envmap import orb_directions, orb_to_world, world_to_orb
from eval.radiance_hdr import read_hdr, write_hdr
from gspi.data.layouts.stanford_orb import export_stanford_orb, import_stanford_orb
from gspi.data.layouts.tensoir import export_tensoir, import_tensoir
from gspi.data.layouts.nerf_synthetic import linear_from_rgba, write_rgba
from tests.fixtures import generated_scene, make_envmap, protocol
from tests.reliability.helpers import run_cli

S = 16  # fixture image size
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def blender_c2w(k: int) -> np.ndarray:
    """A Blender camera on a circle looking at the origin (z up), written independently of
    gspi's conversions."""
    az = 0.7 * k + 0.3
    eye = 3.0 * np.array([np.cos(az) * 0.8, np.sin(az) * 0.8, 0.6])
    back = eye / np.linalg.norm(eye)                       # camera +z (Blender looks along -z)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(back, right), back, eye
    return c2w


def expected_w2c(c2w_blender: np.ndarray) -> np.ndarray:
    return np.linalg.inv(c2w_blender @ FLIP)


def rgba_image(seed: int, size: int = S) -> np.ndarray:
    """8-bit-exact RGBA in [0, 1]: a disc of alpha 1 with a soft edge, random colours."""
    rng = np.random.default_rng(seed)
    r = np.hypot(*np.meshgrid(np.arange(size) - size / 2 + 0.5, np.arange(size) - size / 2 + 0.5))
    alpha = np.clip((size * 0.4 - r) / 2.0, 0.0, 1.0)
    rgb = rng.integers(0, 256, (size, size, 3)) / 255.0
    return np.concatenate([rgb, np.round(alpha * 255)[..., None] / 255.0], -1)


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """One generated scene at 32 px (LPIPS needs 32) with relit ground truth."""
    return generated_scene(tmp_path_factory.mktemp("gen") / "data", 32)


def assert_same_views(a, b, *, splits=None):
    for split in splits or a.views:
        assert [v.id for v in a.views[split]] == [v.id for v in b.views[split]]
        for v, w in zip(a.views[split], b.views[split]):
            np.testing.assert_allclose(w.w2c, v.w2c, atol=1e-12)
            np.testing.assert_allclose(w.K, v.K, rtol=1e-12)
            va, vb = a.view_dir(split, v.id), b.view_dir(split, w.id)
            assert (read_view_file(va, "mask.png") == read_view_file(vb, "mask.png")).all()


# ---------------------------------------------------------------- Radiance .hdr


def test_radiance_hdr_round_trip(tmp_path):
    x = make_envmap(1)
    y = read_hdr(write_hdr(tmp_path / "a.hdr", x))
    assert y.shape == x.shape and (np.abs(y - x) <= x.max(-1, keepdims=True) * 2.0 ** -8).all()
    (tmp_path / "b.hdr").write_bytes(b"not an hdr")
    with pytest.raises(LayoutError, match="b.hdr: not a Radiance"):
        read_hdr(tmp_path / "b.hdr")


# ---------------------------------------------------------------- TensoIR


def write_tensoir_fixture(root, size: int = S):
    """TensoIR_Synthetic/<scene>/{train_000,test_000,test_001} + Environment_Maps/high_res_envmaps_1k."""
    scene = root / "TensoIR_Synthetic" / "toy"
    envs = root / "TensoIR_Synthetic" / "Environment_Maps" / "high_res_envmaps_1k"
    for k, env in enumerate(("sunset", "bridge")):
        write_hdr(envs / f"{env}.hdr", make_envmap(k))
    truth = {}
    for k, folder in enumerate(("test_000", "test_001", "train_000")):
        d = scene / folder
        c2w = blender_c2w(k)
        d.mkdir(parents=True)
        (d / "metadata.json").write_text(json.dumps({
            "imw": size, "imh": size, "cam_angle_x": 0.69, "envmap": "sunset",
            "cam_transform_mat": ",".join(str(x) for x in c2w.reshape(-1))}))
        rgba, albedo, relit = rgba_image(k, size), rgba_image(10 + k, size), rgba_image(20 + k, size)
        n = np.zeros((size, size, 3))
        n[..., 2] = 1.0
        write_rgba(d / "rgba_sunset_000.png", rgba)  # what TensoIR's single-light training reads
        write_rgba(d / "rgba.png", rgba_image(30 + k, size))  # read by no TensoIR loader: must not be used
        write_rgba(d / "albedo.png", albedo)
        write_rgba(d / "normal.png", np.concatenate([(n + 1) / 2, rgba[..., 3:]], -1))
        write_rgba(d / "rgba_bridge.png", relit)
        write_rgba(d / "rgba_sunset_120.png", relit)  # a rotated light without its .hdr: not imported
        truth[folder] = (c2w, rgba, albedo, relit)
    return scene, truth


def test_tensoir_fixture_imports(tmp_path):
    src, truth = write_tensoir_fixture(tmp_path)
    assert detect_format(src) == "tensoir"
    scene = import_tensoir(src, tmp_path / "out")
    assert scene.gt_channels == ("albedo", "relight") and scene.relit_gt == "images"
    assert scene.capture_env == "sunset" and scene.relight_envs == ["bridge"]
    assert [v.id for v in scene.views["test"]] == ["test_000", "test_001"]
    for split, views in scene.views.items():
        for v in views:
            c2w, rgba, albedo, relit = truth[v.id]
            focal = 0.5 * S / math.tan(0.5 * 0.69)  # TensoIR: 0.5 imw / tan(0.5 cam_angle_x)
            np.testing.assert_allclose(v.K, [[focal, 0, S / 2], [0, focal, S / 2], [0, 0, 1]], rtol=1e-12)
            np.testing.assert_allclose(v.w2c, expected_w2c(c2w), atol=1e-12)
            vdir = scene.view_dir(split, v.id)
            mask = rgba[..., 3:] != 0  # TensoIR: ~(alpha == 0)
            assert (read_view_file(vdir, "mask.png") == mask).all()
            assert 0 < ((rgba[..., 3] > 0) & (rgba[..., 3] < 0.5)).sum()  # the rule matters on this fixture
            np.testing.assert_allclose(read_view_file(vdir, "rgb.exr"), linear_from_rgba(rgba), atol=1e-6)
            # TensoIR's albedo: rgb a + (1 - a), used as linear values; gspi stores it sRGB-encoded
            tensoir_linear = albedo[..., :3] * albedo[..., 3:] + (1 - albedo[..., 3:])
            stored = srgb_to_linear(torch.from_numpy(read_view_file(vdir, "albedo.png"))).numpy()
            np.testing.assert_allclose(stored, tensoir_linear * mask, atol=2e-5)
            normal = read_view_file(vdir, "normal.exr")
            a = rgba[..., 3:]  # the normal map's alpha (TensoIR blends to (0, 0, 1) by it)
            n8 = (np.array([128, 128, 255]) / 255.0 * 2.0 - 1.0) * a + np.array([0.0, 0.0, 1.0]) * (1 - a)
            n8 = n8 / np.linalg.norm(n8, axis=-1, keepdims=True)
            np.testing.assert_allclose(normal[mask[..., 0]], n8[mask[..., 0]], atol=1e-6)
            assert (normal[~mask[..., 0]] == 0).all()
            lin = srgb_to_linear(torch.from_numpy(relit[..., :3].astype(np.float32))).numpy() * relit[..., 3:]
            if split == "test":
                np.testing.assert_allclose(read_exr(vdir / "relit_bridge.exr"), lin, atol=1e-6)
            assert not (vdir / "relit_sunset_120.exr").exists()
    np.testing.assert_array_equal(read_exr(scene.envmap_path("bridge")), read_hdr(
        tmp_path / "TensoIR_Synthetic/Environment_Maps/high_res_envmaps_1k/bridge.hdr"))


@pytest.mark.parametrize("preset_name", ["default", "tensoir"])
def test_tensoir_exact_linear_albedo_scores_at_the_cap(tmp_path, lpips_net, preset_name):
    """The albedo TensoIR's loader holds (linear values, blended on white by alpha), written as a
    gspi prediction the normal way (sRGB-encoded albedo.png), scores at the PSNR cap under the
    default protocol and under eval=tensoir (issue 41: 11.9 / 29.5 dB when the reader copied the
    linear values into gspi's sRGB file)."""
    from eval.common.colorspace import linear_to_srgb
    from eval.common.layout import write_material
    from tests.fixtures import preset

    src, truth = write_tensoir_fixture(tmp_path, size=32)  # LPIPS needs 32 px
    scene = import_tensoir(src, tmp_path / "gt")
    pred = tmp_path / "pred" / scene.name
    for v in scene.views["test"]:
        _, rgba, albedo, _ = truth[v.id]
        linear = albedo[..., :3] * albedo[..., 3:] + (1 - albedo[..., 3:])  # TensoIR's albedo
        (pred / "test" / v.id).mkdir(parents=True)
        srgb = linear_to_srgb(torch.from_numpy(linear.astype(np.float32))).numpy()
        write_material(pred / "test" / v.id, "albedo", srgb * (rgba[..., 3:] != 0))
    cfg = protocol(channels=["albedo"]) if preset_name == "default" else preset("tensoir", "eval.channels=[albedo]", "eval.lpips.net=alex")  # PSNR is what is tested
    result = evaluate(tmp_path / "gt", tmp_path / "pred", cfg, net=lpips_net)
    assert result.summary["albedo"]["psnr"] >= 100, result.summary["albedo"]


def test_tensoir_round_trip(generated, tmp_path):
    folder = export_tensoir(generated.root, tmp_path / "tir")
    assert (tmp_path / "tir" / "Environment_Maps" / "high_res_envmaps_1k").is_dir()
    back = import_tensoir(folder, tmp_path / "back")
    assert back.name == generated.name and back.capture_env == generated.capture_env
    assert back.relight_envs == generated.relight_envs and back.gt_channels == ("albedo", "relight")
    assert_same_views(generated, back)
    for v in generated.views["test"]:
        a, b = generated.view_dir("test", v.id), back.view_dir("test", v.id)
        mask = read_view_file(a, "mask.png")[..., 0] > 0.5
        lin = [srgb_to_linear(torch.from_numpy(read_view_file(x, "albedo.png"))).numpy() for x in (a, b)]
        assert np.abs(lin[0] - lin[1]).max() <= 0.5 / 255 + 1e-6  # TensoIR's albedo.png: 8-bit linear
        dn = read_view_file(a, "normal.exr") - read_view_file(b, "normal.exr")
        assert np.abs(dn[mask]).max() < 2.5 / 255
        for env in generated.relight_envs:  # 8-bit sRGB: <= half a step of the encoding, in linear
            x, y = np.clip(read_exr(a / f"relit_{env}.exr"), 0, 1), read_exr(b / f"relit_{env}.exr")
            assert np.abs(x - y)[mask].max() < 0.5 / 255 * 1.1
    for env in [generated.capture_env, *generated.relight_envs]:
        x, y = read_exr(generated.envmap_path(env)), read_exr(back.envmap_path(env))
        assert (np.abs(x - y) <= x.max(-1, keepdims=True) * 2.0 ** -8 + 1e-30).all()


def test_tensoir_missing_metadata_is_one_line(tmp_path):
    src, _ = write_tensoir_fixture(tmp_path)
    (src / "test_001" / "metadata.json").unlink()
    from gspi.cli.data import main
    code, text = run_cli(main, [f"import.src={src}", "import.format=tensoir", f"out={tmp_path / 'o'}"])
    lines = [x for x in text.splitlines() if "error" in x]
    assert code == 2 and len(lines) == 1 and f"{src}/test_001/metadata.json" in lines[0] and "not found" in lines[0]


# ---------------------------------------------------------------- Stanford-ORB


def write_orb_fixture(root, size=2 * S):
    """data/blender_HDR/{obj_scene001, obj_scene002} + data/ground_truth/... at 2 x S px (downsized
    by 2 at import.resolution=S). Returns (capture folder, the written arrays)."""
    data, rng, arrays = root / "data", np.random.default_rng(0), {}
    for cap, n_test in (("obj_scene001", 2), ("obj_scene002", 1)):
        folder, gt = data / "blender_HDR" / cap, data / "ground_truth" / cap
        meta = {}
        for split, n in (("train", 1), ("test", n_test)):
            frames = []
            for k in range(n):
                vid = f"{k:04d}"
                img = rng.uniform(0, 4, (size, size, 3)).astype(np.float32)
                mask = np.round(rgba_image(k, size)[..., 3:])
                write_exr(folder / split / f"{vid}.exr", img)
                write_png(folder / f"{split}_mask" / f"{vid}.png", mask, bits=8)
                c2w = blender_c2w(k + 5 * (split == "test"))
                frames.append({"file_path": f"{split}/{vid}", "transform_matrix": c2w.tolist()})
                arrays[(cap, split, vid)] = (img, mask, c2w)
                if split == "test":
                    (gt / "surface_normal").mkdir(parents=True, exist_ok=True)
                    (gt / "z_depth").mkdir(parents=True, exist_ok=True)
                    normal = np.zeros((size, size, 3), np.float32)
                    normal[..., 2] = 1.0  # facing the camera (Blender camera axes)
                    np.save(gt / "surface_normal" / f"{vid}.npy", normal)
                    np.save(gt / "z_depth" / f"{vid}.npy", np.full((size, size), 3.0, np.float32))
                    write_png(gt / "pseudo_gt_albedo" / f"{vid}.png", rng.integers(0, 256, (size, size, 3)) / 255.0,
                              bits=8)
                    env = np.ones((8, 16, 3), np.float32)
                    env[4, 8] = 100.0  # the texel just below the centre of the map: ahead of the camera
                    write_exr(gt / "env_map" / f"{vid}.exr", env)
            meta[split] = {"camera_angle_x": 0.5, "frames": frames}
            (folder / f"transforms_{split}.json").write_text(json.dumps(meta[split]))
    novel = [{**f, "scene_name": "obj_scene002", "camera_angle_x": 0.5}
             for f in meta["test"]["frames"]]  # obj_scene002's test camera, "aligned"
    (data / "blender_HDR" / "obj_scene001" / "transforms_novel.json").write_text(json.dumps({"frames": novel}))
    return data / "blender_HDR" / "obj_scene001", arrays


def test_stanford_orb_fixture_imports(tmp_path):
    src, arrays = write_orb_fixture(tmp_path)
    assert detect_format(src) == "stanford_orb"
    scene = import_stanford_orb(src, tmp_path / "out", resolution=S)
    assert scene.width == S and scene.gt_channels == ("albedo", "relight") and scene.relit_gt == "images"
    ids = [v.id for v in scene.views["test"]]
    assert ids == ["0000", "0001", "obj_scene002_0000"] and scene.relight_envs == ["obj_scene002_0000"]
    for v in scene.views["test"] + scene.views["train"]:
        cap, vid = ("obj_scene002", "0000") if "_" in v.id else ("obj_scene001", v.id)
        img, mask, c2w = arrays[(cap, v.split, vid)]
        np.testing.assert_allclose(v.w2c, expected_w2c(c2w), atol=1e-12)
        focal = 0.5 * S / math.tan(0.25)  # orb: .5 * BENCHMARK_RESOLUTION / tan(.5 * camera_angle_x)
        np.testing.assert_allclose(v.K[0, 0], focal, rtol=1e-12)
        small_mask = mask.reshape(S, 2, S, 2, 1).mean((1, 3)) > 0.5
        vdir = scene.view_dir(v.split, v.id)
        assert (read_view_file(vdir, "mask.png") == small_mask).all()
        np.testing.assert_allclose(read_view_file(vdir, "rgb.exr"),
                                   img.reshape(S, 2, S, 2, 3).mean((1, 3)) * small_mask, rtol=1e-6)
        if v.split == "test":
            n = read_view_file(vdir, "normal.exr")[small_mask[..., 0]]
            np.testing.assert_allclose(n, np.broadcast_to(c2w[:3, 2], n.shape), atol=1e-6)  # camera +z, world
    relit_view = scene.views["test"][2]
    assert relit_view.gt_channels == ("relight",) and scene.views["test"][0].gt_channels == ("albedo",)
    vdir = scene.view_dir("test", relit_view.id)
    np.testing.assert_array_equal(read_exr(vdir / "relit_obj_scene002_0000.exr"), read_view_file(vdir, "rgb.exr"))
    env = read_exr(scene.envmap_path("obj_scene002_0000"))  # its bright texel lies ahead of the camera
    d = latlong_directions(*env.shape[:2], dtype=torch.float64).numpy()[np.unravel_index(env[..., 0].argmax(),
                                                                                          env.shape[:2])]
    c2w = arrays[("obj_scene002", "test", "0000")][2]
    expected = c2w[:3, :3] @ orb_directions(8, 16)[4, 8]  # the bright texel's world direction
    assert d @ expected > math.cos(math.radians(32))  # within a texel of the 8-row world map


def test_orb_envmap_convention():
    """A constant map converts exactly; a map linear in the direction comes back through
    export and import within the bilinear error."""
    c2w = blender_c2w(1)
    np.testing.assert_allclose(orb_to_world(np.full((8, 16, 3), 2.0, np.float32), c2w), 2.0, rtol=1e-6)
    d = latlong_directions(32, 64, dtype=torch.float64).numpy()
    world = (1.5 + d @ np.array([0.3, -0.2, 0.4]))[..., None].repeat(3, -1).astype(np.float32)
    orb = world_to_orb(world, c2w, 128)
    expected = 1.5 + (orb_directions(128, 256) @ c2w[:3, :3].T) @ np.array([0.3, -0.2, 0.4])
    assert np.abs(orb[..., 0] - expected).max() < 0.02  # bilinear on a 32-row map: ~1 % of the range
    assert np.abs(orb_to_world(orb, c2w, 32) - world).max() < 0.02


def test_stanford_orb_round_trip(generated, tmp_path):
    folder = export_stanford_orb(generated.root, tmp_path / "orb")
    back = import_stanford_orb(folder, tmp_path / "back", resolution=generated.width)
    assert back.name == generated.name and back.gt_channels == ("albedo", "relight")
    assert_same_views(generated, back, splits=["train"])
    own = [v for v in back.views["test"] if v.gt_channels == ("albedo",)]
    relit = [v for v in back.views["test"] if v.gt_channels == ("relight",)]
    assert [v.id for v in own] == [v.id for v in generated.views["test"]]
    assert len(relit) == len(generated.views["test"]) * len(generated.relight_envs)
    for v, w in zip(generated.views["test"], own):
        a, b = generated.view_dir("test", v.id), back.view_dir("test", w.id)
        np.testing.assert_allclose(w.w2c, v.w2c, atol=1e-12)
        assert (read_view_file(a, "mask.png") == read_view_file(b, "mask.png")).all()
        assert np.abs(read_view_file(a, "albedo.png") - read_view_file(b, "albedo.png")).max() <= 0.5 / 255 + 1e-6
        np.testing.assert_allclose(read_view_file(b, "normal.exr"), read_view_file(a, "normal.exr"), atol=1e-6)
        np.testing.assert_array_equal(read_view_file(b, "depth.exr"), read_view_file(a, "depth.exr"))
    env = generated.relight_envs[0]
    for v, w in zip(generated.views["test"], relit):
        assert w.id == f"{generated.name}-{env}_{v.id}" and w.relight_envs == (w.id,)
        np.testing.assert_allclose(w.w2c, v.w2c, atol=1e-12)
        np.testing.assert_array_equal(read_exr(back.view_dir("test", w.id) / f"relit_{w.id}.exr"),
                                      read_exr(generated.view_dir("test", v.id) / f"relit_{env}.exr"))


def test_stanford_orb_npy_only_albedo_imports(generated, tmp_path):
    """ORB's README lists pseudo_gt_albedo/<id>.npy: a ground truth with only those (linear
    float arrays) imports to the same albedo as the PNGs ORB's evaluator reads, within 8 bits;
    a bad array is one line naming it."""
    folder = export_stanford_orb(generated.root, tmp_path / "orb")
    gt_dirs = list((tmp_path / "orb").rglob("pseudo_gt_albedo"))
    assert gt_dirs
    for d in gt_dirs:
        for png in d.glob("*.png"):
            srgb = torch.from_numpy(read_png(png, channels=3))
            np.save(png.with_suffix(".npy"), srgb_to_linear(srgb).numpy())
            png.unlink()
    back = import_stanford_orb(folder, tmp_path / "back", resolution=generated.width)
    for v in generated.views["test"]:
        a, b = generated.view_dir("test", v.id), back.view_dir("test", v.id)
        assert np.abs(read_view_file(a, "albedo.png") - read_view_file(b, "albedo.png")).max() <= 0.5 / 255 + 1e-4
    bad = next(gt_dirs[0].glob("*.npy"))
    np.save(bad, np.full((4, 4), 200.0, np.float32))
    with pytest.raises(LayoutError, match=f"{bad.name}: expected an \\[H, W, 3\\]"):
        import_stanford_orb(folder, tmp_path / "back2", resolution=generated.width)


def test_stanford_orb_missing_transforms_is_one_line(tmp_path):
    src, _ = write_orb_fixture(tmp_path)
    (src / "transforms_test.json").unlink()
    from gspi.cli.data import main
    code, text = run_cli(main, [f"import.src={src}", f"out={tmp_path / 'o'}"])
    lines = [x for x in text.splitlines() if "error" in x]
    assert code == 2 and len(lines) == 1 and f"{src}/transforms_test.json" in lines[0], text


# ---------------------------------------------------------------- NeRO Glossy Synthetic


def test_nero_fixture_imports(tmp_path):
    src = tmp_path / "GlossySynthetic" / "bell"
    src.mkdir(parents=True)
    cams = []
    for k in range(3):
        w2c = expected_w2c(blender_c2w(k))
        K = np.array([[20.0, 0, 8.0], [0, 21.0, 7.5], [0, 0, 1]])
        (src / f"{k}-camera.pkl").write_bytes(pickle.dumps([w2c[:3].astype(np.float32), K.astype(np.float32)]))
        depth = np.where(rgba_image(k)[..., 3:] > 0.5, 3.0, 15.0) / 15.0
        write_png(src / f"{k}-depth.png", depth, bits=16)
        write_png(src / f"{k}.png", rgba_image(k)[..., :3], bits=8)
        cams.append((K, w2c, depth))
    assert detect_format(src) == "nero_glossy"
    scene = import_nero_glossy(src, tmp_path / "out")
    assert scene.gt_channels == () and [v.id for v in scene.views["train"]] == ["0", "1", "2"]
    for v, (K, w2c, depth) in zip(scene.views["train"], cams):
        np.testing.assert_array_equal(v.K, K.astype(np.float32))
        np.testing.assert_array_equal(v.w2c[:3], w2c[:3].astype(np.float32))
        vdir = scene.view_dir("train", v.id)
        mask = depth * 15.0 < 14.5
        assert (read_view_file(vdir, "mask.png") == mask).all()
        np.testing.assert_allclose(read_view_file(vdir, "depth.exr"), np.where(mask, 3.0, 0.0), atol=1e-3)
    (src / "0-camera.pkl").write_bytes(pickle.dumps([__import__("os").system, K]))
    with pytest.raises(LayoutError, match="0-camera.pkl: not a NeRO camera pickle"):
        import_nero_glossy(src, tmp_path / "out2")  # a pickle naming anything but numpy is refused


def test_nero_round_trip_and_missing_cameras(generated, tmp_path):
    back = import_nero_glossy(export_nero_glossy(generated.root, tmp_path / "nero"), tmp_path / "back")
    assert back.name == generated.name and back.gt_channels == ()
    assert_same_views(generated, back)
    for split, views in generated.views.items():
        for v in views:
            a, b = generated.view_dir(split, v.id), back.view_dir(split, v.id)
            assert np.abs(read_view_file(a, "depth.exr") - read_view_file(b, "depth.exr")).max() <= 15 / 65535
    with pytest.raises(LayoutError, match="no <k>-camera.pkl"):
        import_nero_glossy(tmp_path, tmp_path / "x")


def test_unrecognised_folder_is_one_line(tmp_path):
    (tmp_path / "src").mkdir()
    from gspi.cli.data import main
    code, text = run_cli(main, [f"import.src={tmp_path / 'src'}", f"out={tmp_path / 'o'}"])
    lines = [x for x in text.splitlines() if "error" in x]
    assert code == 2 and len(lines) == 1 and "no dataset layout recognised" in lines[0]


# ---------------------------------------------------------------- scoring an imported scene


@pytest.mark.parametrize("layout", ["tensoir", "stanford_orb"])
def test_eval_scores_imported_scene_and_reports_absent(generated, tmp_path, lpips_net, layout):
    """The generated scene (its own maps as the prediction) against its TensoIR / Stanford-ORB
    import: albedo and relighting are scored, roughness and metallic absent, not 0."""
    if layout == "tensoir":
        back = import_tensoir(export_tensoir(generated.root, tmp_path / "x"), tmp_path / "gt")
    else:
        back = import_stanford_orb(export_stanford_orb(generated.root, tmp_path / "x"), tmp_path / "gt",
                                   resolution=generated.width)
    pred = tmp_path / "pred" / generated.name
    for v in generated.views["test"]:
        for c in ("albedo", "roughness", "metallic"):
            (pred / "test" / v.id).mkdir(parents=True, exist_ok=True)
            (pred / "test" / v.id / f"{c}.png").write_bytes((generated.view_dir("test", v.id) / f"{c}.png").read_bytes())
    if layout == "stanford_orb":  # its relighting views are extra test views of the same cameras
        for w in back.views["test"]:
            if w.gt_channels == ("relight",):
                (pred / "test" / w.id).mkdir(parents=True)
                for c in ("albedo", "roughness", "metallic"):
                    src = generated.view_dir("test", w.id.rsplit("_", 1)[1]) / f"{c}.png"
                    (pred / "test" / w.id / f"{c}.png").write_bytes(src.read_bytes())
    result = evaluate(tmp_path / "gt", tmp_path / "pred", protocol(), net=lpips_net)
    assert set(result.summary) == {"albedo", "relight"}
    assert set(result.info["absent_gt"]) == {"roughness", "metallic"}
    assert result.summary["albedo"]["psnr"] > 50          # 8-bit albedo of the layout vs 16-bit
    assert result.summary["relight"]["psnr"] > (35 if layout == "tensoir" else 25)
    n_relit = sum(len(back.view_relight_envs(v)) for v in back.views["test"])
    assert result.info["counts"]["relight"]["images"] == n_relit


def test_eval_refuses_ground_truth_without_channels(generated, tmp_path):
    back = import_nero_glossy(export_nero_glossy(generated.root, tmp_path / "x"), tmp_path / "gt")
    with pytest.raises(LayoutError, match="provides none of eval.channels"):
        evaluate(tmp_path / "gt", back.root.parent, protocol(), net=object())


def test_nero_glossy_real_is_refused_in_one_line_saying_why(tmp_path):
    """NeRO's Glossy Real captures (COLMAP cameras, no masks) are not read: detection and an
    explicit import.format=nero_glossy both say so, naming the folder, through gspi-data too."""
    src = tmp_path / "GlossyReal" / "bear"
    (src / "colmap" / "sparse" / "0").mkdir(parents=True)
    (src / "images").mkdir()
    (src / "object_point_cloud.ply").write_bytes(b"ply\n")
    with pytest.raises(LayoutError, match="bear: a NeRO Glossy Real capture.*not supported.*no masks"):
        detect_format(src)
    with pytest.raises(LayoutError, match="Glossy Real capture"):
        import_nero_glossy(src, tmp_path / "out")
    from gspi.cli.data import main
    code, text = run_cli(main, [f"import.src={src}", f"out={tmp_path / 'o'}"])
    lines = [x for x in text.splitlines() if "error" in x]
    assert code == 2 and len(lines) == 1 and "Glossy Real" in lines[0], text
