"""HDR environment files: the documented convention, bad files, environment sets, the npm
asset install (gspi.data.hdri, gspi.data.env_sets, gspi.data.pmndrs_assets)."""
from __future__ import annotations

import base64
import io
import math
import tarfile

import numpy as np
import pytest
import torch

from eval.common.imageio import write_exr
from eval.common.layout import read_scene
from eval.relight import split_sum
from gspi.data import pmndrs_assets
from gspi.data.env_sets import assign_environments, environment_sets, resolve_env_set
from gspi.data.generate import BenchmarkConfig, generate_dataset, scene_recipes
from gspi.data.hdri import POLYHAVEN_CAPTURE, POLYHAVEN_HELDOUT, HDRIError, load_hdri, read_hdri


def _spot_file(path, h=64, row=16, col=32, value=500.0):
    """A dim grey map with one bright 2x2 texel block whose top-left texel is (row, col)."""
    env = np.full((h, 2 * h, 3), 0.05, np.float32)
    env[row:row + 2, col:col + 2] = value
    write_exr(path, env)
    return path


def test_convention_feature_lands_where_docs_say(tmp_path):
    # docs/DATA.md: row 0 = zenith, image centre = +x, a quarter width left of centre = +y.
    # A spot straddling row H/4 (elevation 45 deg) and column W/4 (azimuth +90 deg) is at
    # direction (0, 1, 1)/sqrt(2).
    h = 64
    path = _spot_file(tmp_path / "spot.exr", h=h, row=h // 4 - 1, col=h // 2 - 1)
    env = load_hdri(path, 32)                       # resampled to 32 rows, exposure normalised
    assert env.shape == (32, 64, 3)
    expected = torch.tensor([0.0, 1.0, 1.0]) / math.sqrt(2)
    rows, cols = torch.nonzero(env[..., 0] == env[..., 0].max(), as_tuple=True)
    # The 32-row texels around (0, 1, 1)/sqrt 2: rows 7-8 (elevation 45), columns 15-16 (+y).
    assert set(rows.tolist()) <= {7, 8} and set(cols.tolist()) <= {15, 16}
    # A diffuse white surface is brightest when facing the spot, dark facing away.
    normals = torch.tensor([[0.0, 1.0, 1.0], [0.0, -1.0, 1.0], [1.0, 0.0, 1.0], [-1, 0, 1.0],
                            [0.0, -1.0, -1.0]]) / math.sqrt(2)
    rgb = split_sum(torch.ones(5, 3), torch.ones(5, 1), torch.zeros(5, 1), normals, normals, env)
    lum = rgb.mean(-1)
    assert int(lum.argmax()) == 0 and float(lum[0]) > 1.8 * float(lum[1:].max())
    assert float(lum[1]) < 0.1 * float(lum[0]) and float(lum[4]) < 0.1 * float(lum[0])
    # Exposure: white Lambertian facing the brightest direction ~ radiance 1 (white_radiance).
    assert 0.8 < float(lum[0]) < 1.05
    assert torch.allclose(normals[0], expected)


def test_bad_hdri_files_name_the_file(tmp_path):
    write_exr(tmp_path / "square.exr", np.ones((16, 16, 3), np.float32))
    with pytest.raises(HDRIError, match="square.exr.*2:1"):
        read_hdri(tmp_path / "square.exr")
    bad = np.ones((16, 32, 3), np.float32)
    bad[3, 4, 1] = np.nan
    (tmp_path / "nan.exr").write_bytes(b"")
    import OpenEXR
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                      {"RGB": bad}) as f:
        f.write(str(tmp_path / "nan.exr"))
    with pytest.raises(HDRIError, match="nan.exr.*NaN"):
        read_hdri(tmp_path / "nan.exr")
    write_exr(tmp_path / "black.exr", np.zeros((16, 32, 3), np.float32))
    with pytest.raises(HDRIError, match="black.exr"):
        read_hdri(tmp_path / "black.exr")
    neg = np.ones((16, 32, 3), np.float32)
    neg[0, 0] = -5.0
    write_exr(tmp_path / "neg.exr", neg)
    assert read_hdri(tmp_path / "neg.exr").min() == 0.0  # ringing clamped, documented


def test_environment_sets(tmp_path):
    assert not set(POLYHAVEN_CAPTURE) & set(POLYHAVEN_HELDOUT)
    assert len(POLYHAVEN_CAPTURE) + len(POLYHAVEN_HELDOUT) == len(pmndrs_assets.HDRI_NAMES)
    a = _spot_file(tmp_path / "mine_a.exr")
    b = _spot_file(tmp_path / "mine_b.exr", row=40)
    capture, relight = environment_sets("procedural", [str(a), str(b), "neon"])
    assert relight == {"mine_a": str(a.resolve()), "mine_b": str(b.resolve()),
                       "neon": "procedural"}
    with pytest.raises(ValueError, match="disjoint"):
        environment_sets([str(a)], [str(a)])
    with pytest.raises(FileNotFoundError, match="nope.exr"):
        resolve_env_set([str(tmp_path / "nope.exr")], "heldout")
    cfg = BenchmarkConfig(num_train_scenes=1, num_val_scenes=0, num_test_scenes=1,
                          num_relight_envs=2)
    base = scene_recipes(0, cfg)
    mine = scene_recipes(0, BenchmarkConfig(**{**cfg.__dict__, "relight_envs": [str(a), str(b)]}))
    for r0, r1 in zip(base, mine):
        assert r1["relight_envs"] == ["mine_a", "mine_b"]
        assert r1["capture_env"] in capture
        # Only the relighting set changed: everything else, the capture env included, is kept.
        assert {k: v for k, v in r0.items() if k != "relight_envs"} == \
            {k: v for k, v in r1.items() if k != "relight_envs"}
    both = scene_recipes(0, BenchmarkConfig(**{**cfg.__dict__, "relight_envs": [str(a)],
                                               "capture_envs": [str(b)], "num_relight_envs": 1}))
    assert all(r["capture_env"] == "mine_b" and r["relight_envs"] == ["mine_a"] for r in both)
    with pytest.raises(ValueError, match="num_relight_envs"):
        assign_environments(base[0], 0, ["x"], ["a"], 2)


def test_user_hdri_dataset(tmp_path):
    a = _spot_file(tmp_path / "mine_a.exr")
    cfg = BenchmarkConfig(num_train_scenes=0, num_val_scenes=0, num_test_scenes=1, image_size=16,
                          env_height=16, num_test_views=1, num_val_views=0, num_relight_envs=1,
                          point_clouds=False, contact_sheets=False, relight_envs=[str(a)],
                          lattice={"num_views": 4, "radius": 3.0, "fov_deg": 45.0,
                                   "min_elevation_deg": 0.0})
    stats = generate_dataset(tmp_path / "d", cfg, seed=0)
    scene = read_scene(tmp_path / "d" / stats["scenes"][0]["name"])
    assert scene.relight_envs == ["mine_a"]
    assert (scene.view_dir("test", "t00") / "relit_mine_a.exr").is_file()
    assert torch.allclose(torch.from_numpy(read_hdri(scene.envmap_path("mine_a"))),
                          load_hdri(a, 16), rtol=1e-6)


def _fake_tgz(payload: bytes) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        text = f"export default 'data:application/exr;base64,{base64.b64encode(payload).decode()}'"
        info = tarfile.TarInfo("package/hdri/city.exr.js")
        info.size = len(text)
        tar.addfile(info, io.BytesIO(text.encode()))
    return buf.getvalue()


def test_asset_install_checks_checksum_and_decodes(tmp_path, monkeypatch):
    assert pmndrs_assets.decode_module(
        "export default 'data:model/gltf-binary;base64,Z2xURg=='", "x.js") == b"glTF"
    with pytest.raises(pmndrs_assets.AssetsUnavailable, match="x.js"):
        pmndrs_assets.decode_module("export default 42", "x.js")
    monkeypatch.setenv("GSPI_CACHE", str(tmp_path / "cache"))
    tgz = tmp_path / "pmndrs-assets-1.7.0.tgz"
    tgz.write_bytes(_fake_tgz(b"not the real package"))
    with pytest.raises(pmndrs_assets.AssetsUnavailable, match="SHA-256"):
        pmndrs_assets.install(tgz)
    assert not (tmp_path / "cache" / pmndrs_assets.FOLDER / "MANIFEST").exists()
    import eval.common.npm_package

    monkeypatch.setattr(eval.common.npm_package.shutil, "which", lambda _: None)
    with pytest.raises(pmndrs_assets.AssetsUnavailable, match="npm not found"):
        pmndrs_assets.install()


def test_polyhaven_files_follow_the_convention():
    """The installed Poly Haven maps: sky above (row 0 side brighter), sun of `sky` up high."""
    root = pmndrs_assets.asset_root()
    if not (root / "MANIFEST").is_file():
        pytest.skip(f"{pmndrs_assets.PACKAGE} not installed (python -m gspi.data.pmndrs_assets)")
    for name in ("sky", "city", "forest", "park"):
        env = read_hdri(root / "hdri" / f"{name}.exr")
        h = env.shape[0]
        assert env[: h // 4].mean() > 3 * env[-h // 4:].mean(), name
    sky = read_hdri(root / "hdri" / "sky.exr")
    row = int(np.unravel_index(sky.mean(-1).argmax(), sky.shape[:2])[0])
    assert row < sky.shape[0] // 2  # the sun is above the horizon
