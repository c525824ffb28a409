"""The CPU mesh renderer (baselines/mesh_render.py) and the MaterialAnything import.

The reference is analytic: two textured squares (planes z = 0 and z = 0.4, UV linear in x, y)
seen by the fixture's test cameras; every pixel ray is intersected with both planes here, the
nearest hit inside its square gives (u, v), and the texture is looked up by a numpy bilinear
sampler written here (pixel centres, v up, clamped at the border).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from baselines.adapter import AdapterError, get_adapter, load_method_config
from baselines.mesh_render import MeshError, read_obj, render_uv_maps
from eval.common.layout import read_view_file
from tests.fixtures import make_scene

SQUARES = ((0.0, 1.0), (0.4, 0.5))  # (height z, half size) of each textured square
Q16 = 0.5 / 65535 + 1e-7


def write_squares_obj(path: Path) -> Path:
    """Two squares, each as a quad face (fan-triangulated by the reader), UV = (x/2s + 1/2, ...)."""
    lines, k = ["mtllib squares.mtl", "o squares"], 0
    for z, s in SQUARES:
        corners = [(-s, -s), (s, -s), (s, s), (-s, s)]
        lines += [f"v {x} {y} {z}" for x, y in corners]
        lines += [f"vt {x / (2 * s) + 0.5} {y / (2 * s) + 0.5}" for x, y in corners]
        lines.append("usemtl m")
        lines.append("f " + " ".join(f"{k + i}/{k + i}" for i in (1, 2, 3, 4)))
        k += 4
    path.write_text("\n".join(lines) + "\n")
    return path


def bilinear(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    h, w = tex.shape[:2]
    x = np.clip(u * w - 0.5, 0, w - 1)
    y = np.clip((1 - v) * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    return ((1 - fy) * ((1 - fx) * tex[y0, x0] + fx * tex[y0, x1])
            + fy * ((1 - fx) * tex[y1, x0] + fx * tex[y1, x1]))


def reference_maps(view, size: int, textures: dict, squares=SQUARES) -> tuple[np.ndarray, dict]:
    j, i = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="xy")
    R, t = view.w2c[:3, :3], view.w2c[:3, 3]
    origin = -R.T @ t
    d = (np.stack([j, i, np.ones_like(j)], -1) @ np.linalg.inv(view.K).T) @ R
    best = np.full((size, size), np.inf)
    uv = np.zeros((size, size, 2))
    for z, s in squares:
        dist = (z - origin[2]) / d[..., 2]
        p = origin + dist[..., None] * d
        hit = (dist > 0) & (np.abs(p[..., 0]) <= s) & (np.abs(p[..., 1]) <= s) & (dist < best)
        best = np.where(hit, dist, best)
        uv[hit] = p[hit][:, :2] / (2 * s) + 0.5
    covered = np.isfinite(best)
    maps = {}
    for name, tex in textures.items():
        out = np.zeros((size, size, tex.shape[-1]))
        out[covered] = bilinear(tex, uv[covered, 0], uv[covered, 1])
        maps[name] = out
    return covered, maps


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene(tmp_path_factory.mktemp("gt"), "plate", size=24, seed=2, num_test=3)


def textures(seed=0):
    rng = np.random.default_rng(seed)
    return {"albedo": np.round(rng.uniform(size=(16, 12, 3)) * 255) / 255,
            "rm": np.round(rng.uniform(size=(8, 8, 3)) * 255) / 255}


def test_renderer_matches_ray_casting(scene, tmp_path):
    mesh = read_obj(write_squares_obj(tmp_path / "squares.obj"))
    assert mesh.faces.shape == (4, 3)
    tex = textures()
    for view in scene.split_views("test"):
        covered, maps = render_uv_maps(mesh, tex, view.K, view.w2c, 24, 24)
        ref_cov, ref = reference_maps(view, 24, tex)
        assert covered.sum() > 100 and np.array_equal(covered, ref_cov)
        _, lower_only = reference_maps(view, 24, tex, SQUARES[:1])
        assert (lower_only["albedo"] != ref["albedo"]).any()  # the upper square occludes
        for name in tex:
            np.testing.assert_allclose(maps[name], ref[name], atol=1e-9, err_msg=name)


def test_obj_without_uvs_is_refused(tmp_path):
    (tmp_path / "a.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match=r"a\.obj:4: face without texture coordinates"):
        read_obj(tmp_path / "a.obj")
    with pytest.raises(MeshError, match="mesh file not found"):
        read_obj(tmp_path / "b.obj")


def save_rgb(path: Path, x: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(x * 255).astype(np.uint8), "RGB").save(path)


def test_materialanything_import_renders_uv_textures(scene, tmp_path):
    model = tmp_path / "model"
    write_squares_obj(model.parent / "squares.obj")
    (model / "generate" / "material").mkdir(parents=True)
    (model / "input_mesh.obj").write_text((model.parent / "squares.obj").read_text())
    tex = textures(1)
    save_rgb(model / "generate" / "material" / "final_albedo_after.png", tex["albedo"])
    save_rgb(model / "generate" / "material" / "final_rm_after.png", tex["rm"])
    cfg = load_method_config("materialanything")
    pred = get_adapter("materialanything").import_outputs(model, scene.root, tmp_path / "pred", cfg)
    for view in scene.split_views("test"):
        _, ref = reference_maps(view, 24, tex)
        vdir = pred / "test" / view.id
        np.testing.assert_allclose(read_view_file(vdir, "albedo.png"), ref["albedo"], atol=Q16)
        np.testing.assert_allclose(read_view_file(vdir, "roughness.png")[..., 0],
                                   ref["rm"][..., 1], atol=Q16)
        np.testing.assert_allclose(read_view_file(vdir, "metallic.png")[..., 0],
                                   ref["rm"][..., 2], atol=Q16)
    # without the copied input mesh and without `mesh`, the error names the missing file
    (model / "input_mesh.obj").unlink()
    with pytest.raises(AdapterError, match=r"input_mesh\.obj: mesh file not found"):
        get_adapter("materialanything").import_outputs(model, scene.root, tmp_path / "p2", cfg)
    (model / "generate" / "material" / "final_rm_after.png").unlink()
    with pytest.raises(AdapterError, match=r"final_rm_after\.png: missing"):
        get_adapter("materialanything").import_outputs(
            model, scene.root, tmp_path / "p3", {**cfg, "mesh": str(tmp_path / "squares.obj")})
