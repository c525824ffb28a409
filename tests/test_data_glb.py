"""glTF/GLB import: GT maps from known textures and factors, masks, unit frame, several
primitives, bad files, the CLI (gspi.data.assets.gltf, gspi.data.assets.mesh_render, gspi.data.assets.glb_import)."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.common.layout import read_scene, read_splits, read_view_file
from gspi.data.assets.gltf import GLTFError, read_gltf
from gspi.data.lattice import intrinsics_from_fov, look_at_w2c
from gspi.data.assets.mesh_render import render_mesh_views, unit_frame_mesh
from tests.gltf_fixtures import BLOCKS, FACTOR, MR_BLOCKS, blocky, quad_glb

trimesh = pytest.importorskip("trimesh")
Image = pytest.importorskip("PIL.Image")


def front_view(mesh, size=32, env=None):
    """View from world -y (the quad's front), up +z: image right = +x, top = +z."""
    K = intrinsics_from_fov(45.0, size, size)
    w2c = look_at_w2c(np.array([0.0, -3.0, 0.0]))
    env = torch.ones(8, 16, 3) if env is None else env
    return render_mesh_views(mesh, [(K, w2c, 0)], size, size, env=env, supersample=2)[0]


def test_textures_and_factors_give_exact_gt_maps(tmp_path):
    mesh = unit_frame_mesh(read_gltf(quad_glb(tmp_path / "quad.glb")))
    assert np.isclose(np.linalg.norm(mesh.vertices, axis=-1).max(), 1.0)
    r = front_view(mesh)
    # Quad half-size 1/sqrt 2 after normalisation, at distance 3, 45 deg fov, 32 px:
    # it covers pixels ~[6.9, 25.1); the centres of its four blocks are at pixels 11 and 20.
    inside = r.mask[8:24, 8:24]
    outside = np.concatenate([r.mask[:6].ravel(), r.mask[26:].ravel()])
    assert inside.all() and not outside.any()
    for (bi, bj), (y, x) in {(0, 0): (11, 11), (0, 1): (11, 20), (1, 0): (20, 11),
                             (1, 1): (20, 20)}.items():
        lin = FACTOR * srgb_to_linear(torch.tensor(BLOCKS[bi, bj] / 255.0)).numpy()
        want = linear_to_srgb(torch.tensor(lin)).numpy()
        np.testing.assert_allclose(r.albedo_srgb[y, x], want, atol=1e-5)
        np.testing.assert_allclose(r.roughness[y, x, 0], 0.5 * MR_BLOCKS[bi, bj, 1] / 255,
                                   atol=1e-6)
        np.testing.assert_allclose(r.metallic[y, x, 0], MR_BLOCKS[bi, bj, 2] / 255, atol=1e-6)
    np.testing.assert_allclose(r.normal[16, 16], [0.0, -1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(r.depth[16, 16, 0], 3.0, atol=1e-4)
    assert (r.albedo_srgb[~r.mask] == 0).all() and (r.depth[~r.mask] == 0).all()


def test_several_primitives_and_node_transforms(tmp_path):
    a = trimesh.creation.box(extents=[1, 1, 1])
    b = trimesh.creation.box(extents=[1, 1, 1])
    for m, colour, rough in ((a, [255, 0, 0, 255], 0.2), (b, [0, 0, 255, 255], 0.9)):
        m.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(
            baseColorFactor=colour, roughnessFactor=rough, metallicFactor=0.0))
    scene = trimesh.Scene()
    scene.add_geometry(a, transform=trimesh.transformations.translation_matrix([-2.0, 5, 0]))
    scene.add_geometry(b, transform=trimesh.transformations.translation_matrix([2.0, 5, 0]))
    path = tmp_path / "two.glb"
    path.write_bytes(scene.export(file_type="glb"))
    asset = read_gltf(path)
    assert len(asset.primitives) == 2
    mesh = unit_frame_mesh(asset)
    np.testing.assert_allclose(0.5 * (mesh.vertices.min(0) + mesh.vertices.max(0)), 0, atol=1e-9)
    np.testing.assert_allclose(mesh.center, [0.0, 0.0, 5.0])  # glTF y = 5 -> world z = 5
    r = front_view(mesh, size=48)
    left, right = r.mask[:, :24], r.mask[:, 24:]
    assert left.sum() > 20 and right.sum() > 20
    red, blue = r.albedo_srgb[:, :24][left], r.albedo_srgb[:, 24:][right]  # red box at -x
    assert np.allclose(red, [1.0, 0.0, 0.0]) and np.allclose(blue, [0.0, 0.0, 1.0])
    assert np.allclose(r.roughness[:, :24][left], 0.2)
    assert np.allclose(r.roughness[:, 24:][right], 0.9)


def _glb(doc: dict, binary: bytes = b"") -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<I4s", len(js), b"JSON") + js
    if binary:
        chunks += struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def _triangle_doc(**extra) -> tuple[dict, bytes]:
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32).tobytes()
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0}], "buffers": [{"byteLength": len(pos)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]}
    for key, value in extra.items():
        doc[key] = value
    return doc, pos


def test_bad_glb_inputs(tmp_path):
    doc, pos = _triangle_doc()
    (tmp_path / "nomat.glb").write_bytes(_glb(doc, pos))
    asset = read_gltf(tmp_path / "nomat.glb")  # fallback: the spec's default material
    m = asset.primitives[0].material
    assert (m.base_color == 1).all() and m.roughness == 1 and m.metallic == 1
    assert any("default material" in s for s in asset.ignored)

    doc, pos = _triangle_doc(materials=[{"pbrMetallicRoughness": {
        "baseColorFactor": [0.2, 0.4, 0.6, 1], "baseColorTexture": {"index": 0}}}],
        extensionsUsed=["KHR_materials_transmission"])
    doc["meshes"][0]["primitives"][0]["material"] = 0
    (tmp_path / "nouv.glb").write_bytes(_glb(doc, pos))
    asset = read_gltf(tmp_path / "nouv.glb")  # texture without UVs: factor only, stated
    m = asset.primitives[0].material
    assert m.base_color_texture is None and np.allclose(m.base_color, [0.2, 0.4, 0.6])
    assert "extension KHR_materials_transmission" in asset.ignored
    assert not m.double_sided and not m.outside_brdf  # the glTF default: single-sided, culled

    doc["materials"][0].update(alphaMode="BLEND", doubleSided=True,
                               extensions={"KHR_materials_transmission": {"transmissionFactor": 1}})
    (tmp_path / "blend.glb").write_bytes(_glb(doc, pos))
    blend = read_gltf(tmp_path / "blend.glb")
    assert blend.primitives[0].material.outside_brdf == ("alphaMode BLEND", "KHR_materials_transmission")
    assert "materials[0]: alphaMode BLEND drawn as opaque metallic-roughness (outside_brdf mask)" in blend.ignored
    assert any("without TEXCOORD_0" in s for s in asset.ignored)

    doc, pos = _triangle_doc(extensionsRequired=["EXT_meshopt_compression"])
    (tmp_path / "meshopt.glb").write_bytes(_glb(doc, pos))
    with pytest.raises(GLTFError, match="meshopt.glb.*EXT_meshopt_compression"):
        read_gltf(tmp_path / "meshopt.glb")

    good = quad_glb(tmp_path / "quad.glb").read_bytes()
    (tmp_path / "cut.glb").write_bytes(good[: len(good) // 2])
    with pytest.raises(GLTFError, match="cut.glb.*truncated"):
        read_gltf(tmp_path / "cut.glb")
    (tmp_path / "junk.glb").write_bytes(b"not a gltf file at all")
    with pytest.raises(GLTFError, match="junk.glb"):
        read_gltf(tmp_path / "junk.glb")

    doc, pos = _triangle_doc()
    doc["meshes"][0]["primitives"][0]["mode"] = 1
    (tmp_path / "lines.glb").write_bytes(_glb(doc, pos))
    with pytest.raises(GLTFError, match="lines.glb.*not triangles"):
        read_gltf(tmp_path / "lines.glb")


def test_cli_imports_a_folder_with_splits(tmp_path):
    from gspi.cli.data import run

    src = tmp_path / "objects"
    (src / "train").mkdir(parents=True)
    (src / "test").mkdir()
    quad_glb(src / "train" / "quad_a.glb")
    quad_glb(src / "test" / "quad_b.glb", textured=False)
    result = run(_tiny_import_cfg(tmp_path, src, num_test_views=2, num_val_views=1))
    assert result["mode"] == "import_glb"
    assert read_splits(tmp_path / "out") == {"train": ["quad_a"], "val": [], "test": ["quad_b"]}
    scene = read_scene(tmp_path / "out" / "quad_b")
    assert len(scene.views["train"]) == 4 and len(scene.views["test"]) == 2
    t00 = scene.view_dir("test", "t00")
    assert (t00 / f"relit_{scene.relight_envs[0]}.exr").is_file()
    albedo = read_view_file(t00, "albedo.png")
    mask = read_view_file(t00, "mask.png")[..., 0] > 0.5
    want = linear_to_srgb(torch.tensor(FACTOR)).numpy()
    assert mask.any() and np.abs(albedo[mask] - want).max() <= 1 / 255 + 1e-6
    assert json.loads((scene.root / "scene.json").read_text())["generator"]["family"] == "glb"


def test_16_bit_greyscale_texture_is_read_at_full_depth():
    from gspi.data.assets.gltf import image_rgba

    grey = Image.fromarray(np.array([[0, 32768], [65535, 13107]], np.uint16))   # mode I;16
    assert grey.mode.startswith("I;16")
    np.testing.assert_allclose(image_rgba(grey)[..., 0], [[0, 32768 / 65535], [1, 0.2]], atol=1e-9)
    assert image_rgba(grey).shape == (2, 2, 4) and (image_rgba(grey)[..., 3] == 1).all()
    rgb8 = Image.fromarray(np.full((1, 1, 3), 51, np.uint8))
    np.testing.assert_allclose(image_rgba(rgb8)[..., :3], 0.2)


def test_a_node_scaled_to_zero_is_skipped_and_named(tmp_path):
    doc, pos = _triangle_doc()
    doc["scenes"] = [{"nodes": [0, 1]}]
    doc["nodes"] = [{"mesh": 0}, {"mesh": 0, "scale": [0.0, 0.0, 0.0]}]
    (tmp_path / "zero.glb").write_bytes(_glb(doc, pos))
    asset = read_gltf(tmp_path / "zero.glb")
    assert len(asset.primitives) == 1
    assert any("nodes[1]: degenerate transform" in s for s in asset.ignored)
    doc["scenes"] = [{"nodes": [1]}]
    (tmp_path / "only_zero.glb").write_bytes(_glb(doc, pos))
    with pytest.raises(GLTFError, match="only_zero.glb.*no triangle primitives"):
        read_gltf(tmp_path / "only_zero.glb")


def _tiny_import_cfg(tmp_path, src, **data):
    """gspi-data's config importing `src` into tmp_path/out at 16 px, 4 lattice views (`data`: overrides)."""
    conf = Path(__file__).resolve().parents[1] / "conf"
    cfg = OmegaConf.load(conf / "gspi_data.yaml")
    cfg.data = OmegaConf.load(conf / "data" / "tiny.yaml")
    cfg.out = str(tmp_path / "out")
    cfg["import"].glb = str(src)
    cfg.data.update({"image_size": 16, "num_test_views": 1, "num_val_views": 0, "num_relight_envs": 1,
                     "point_clouds": False, "contact_sheets": False, **data})
    cfg.lattice.num_views = 4
    return cfg


def test_folder_import_recurses_skips_a_bad_file_and_keeps_the_rest(tmp_path):
    """Sub-folders are searched, a bad file is named and skipped, every good asset is written
    with splits.json, and each asset's environments do not depend on its neighbours."""
    from gspi.cli.data import run

    src = tmp_path / "objects"
    (src / "bottle").mkdir(parents=True)
    quad_glb(src / "bottle" / "quad_sub.glb")
    quad_glb(src / "quad_top.glb", textured=False)
    (src / "broken.glb").write_bytes(b"not a gltf file at all")
    result = run(_tiny_import_cfg(tmp_path, src))
    assert [f["file"] for f in result["failed"]] == [str(src / "broken.glb")]
    assert "broken.glb" in result["failed"][0]["error"]
    assert read_splits(tmp_path / "out")["test"] == ["quad_sub", "quad_top"]
    gen = json.loads((tmp_path / "out" / "quad_sub" / "scene.json").read_text())["generator"]
    assert gen["name"] == "quad_sub" and gen["importer"] == "gspi-glb-import"
    alone = tmp_path / "alone"
    alone.mkdir()
    quad_glb(alone / "quad_sub.glb")
    run(_tiny_import_cfg(tmp_path / "second", alone))
    a = read_scene(tmp_path / "out" / "quad_sub")
    b = read_scene(tmp_path / "second" / "out" / "quad_sub")
    assert (a.capture_env, a.relight_envs) == (b.capture_env, b.relight_envs)
    np.testing.assert_array_equal(a.views["test"][0].w2c, b.views["test"][0].w2c)


def _png(blocks: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    Image.fromarray(blocky(blocks)).save(buf, format="PNG")  # RGB, or RGBA for 4 channels
    return buf.getvalue()


def _feature_quad(path, *, texinfo=None, sampler=None, colors=None, uv=None, uv1=None, alpha=None,
                  material=None) -> Path:
    """A 2x2 quad (glTF x-y plane, facing +z) with BLOCKS as its base colour texture; UV (0, 0)
    at its top-left corner (glTF convention), optional COLOR_0, TEXCOORD_1, sampler, texture info,
    per-block texture alpha [2, 2] (uint8) and material keys (alphaMode, doubleSided, ...)."""
    pos = np.array([[-1, 1, 0], [1, 1, 0], [-1, -1, 0], [1, -1, 0]], np.float32)
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], np.float32) if uv is None else np.asarray(uv, np.float32)
    idx = np.array([0, 2, 1, 1, 2, 3], np.uint16)
    arrays = [("VEC3", 5126, pos), ("VEC2", 5126, uv), ("SCALAR", 5123, idx)]
    attrs = {"POSITION": 0, "TEXCOORD_0": 1}
    if colors is not None:
        attrs["COLOR_0"] = len(arrays)
        arrays.append(("VEC3", 5126, np.asarray(colors, np.float32)))
    if uv1 is not None:
        attrs["TEXCOORD_1"] = len(arrays)
        arrays.append(("VEC2", 5126, np.asarray(uv1, np.float32)))
    blob, views, accessors = b"", [], []
    for k, (kind, comp, arr) in enumerate(arrays):
        data = arr.tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        accessors.append({"bufferView": k, "componentType": comp, "count": len(arr), "type": kind})
        blob += data + b"\0" * (-len(data) % 4)
    png = _png(BLOCKS if alpha is None else np.concatenate([BLOCKS, np.asarray(alpha, np.uint8)[..., None]], -1))
    views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(png)})
    blob += png
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "buffers": [{"byteLength": len(blob)}], "bufferViews": views, "accessors": accessors,
           "images": [{"bufferView": len(views) - 1, "mimeType": "image/png"}],
           "textures": [{"source": 0, **({"sampler": 0} if sampler else {})}],
           "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0, **(texinfo or {})},
                                                   "metallicFactor": 0.0}, **(material or {})}],
           "meshes": [{"primitives": [{"attributes": attrs, "indices": 2, "material": 0}]}]}
    if sampler:
        doc["samplers"] = [sampler]
    if texinfo and "extensions" in texinfo:
        doc["extensionsUsed"] = ["KHR_texture_transform"]
        doc["extensionsRequired"] = ["KHR_texture_transform"]
    path.write_bytes(_glb(doc, blob))
    return path


def _block_colours(path) -> dict:
    """Rendered sRGB albedo at the centres of the quad's four blocks, keyed like BLOCKS."""
    r = front_view(unit_frame_mesh(read_gltf(path)))
    return {(bi, bj): r.albedo_srgb[y, x] for (bi, bj), (y, x) in
            {(0, 0): (11, 11), (0, 1): (11, 20), (1, 0): (20, 11), (1, 1): (20, 20)}.items()}


def test_texture_transform_offset_rotation_scale_and_texcoord(tmp_path):
    """KHR_texture_transform (required): the fail mark of not honouring it is the untransformed
    texture, so each case asserts on the block that lands where."""
    plain = _block_colours(_feature_quad(tmp_path / "plain.glb"))
    for (bi, bj), got in plain.items():
        np.testing.assert_allclose(got, BLOCKS[bi, bj] / 255, atol=1e-5)
    ext = lambda **t: {"extensions": {"KHR_texture_transform": t}}  # noqa: E731
    shifted = _block_colours(_feature_quad(tmp_path / "shift.glb", texinfo=ext(offset=[0.5, 0.0])))
    for (bi, bj), got in shifted.items():       # u + 0.5 (REPEAT): left and right swap
        np.testing.assert_allclose(got, BLOCKS[bi, 1 - bj] / 255, atol=1e-5)
    flipped = _block_colours(_feature_quad(tmp_path / "flip.glb", texinfo=ext(scale=[-1.0, 1.0])))
    for (bi, bj), got in flipped.items():       # u -> -u (REPEAT): mirrored left-right
        np.testing.assert_allclose(got, BLOCKS[bi, 1 - bj] / 255, atol=1e-5)
    turned = _block_colours(_feature_quad(tmp_path / "rot.glb", texinfo=ext(rotation=np.pi / 2)))
    for (bi, bj), got in turned.items():        # (u, v) -> (v, -u): a quarter turn
        np.testing.assert_allclose(got, BLOCKS[1 - bj, bi] / 255, atol=1e-5)
    uv1 = [[1, 0], [0, 0], [1, 1], [0, 1]]      # TEXCOORD_1 mirrored left-right, selected by the extension
    by_set = _block_colours(_feature_quad(tmp_path / "uv1.glb", uv1=uv1, texinfo=ext(texCoord=1)))
    for (bi, bj), got in by_set.items():
        np.testing.assert_allclose(got, BLOCKS[bi, 1 - bj] / 255, atol=1e-5)
    asset = read_gltf(tmp_path / "rot.glb")
    assert not any("KHR_texture_transform" in s for s in asset.ignored)


def test_vertex_colours_multiply_the_base_colour(tmp_path):
    colours = [[0.5, 0.5, 0.5]] * 4
    got = _block_colours(_feature_quad(tmp_path / "col.glb", colors=colours))
    for (bi, bj), value in got.items():
        lin = 0.5 * srgb_to_linear(torch.tensor(BLOCKS[bi, bj] / 255.0)).numpy()
        np.testing.assert_allclose(value, linear_to_srgb(torch.tensor(lin)).numpy(), atol=1e-5)


def test_sampler_wrap_modes(tmp_path):
    """UVs 0..2 over the quad (covering pixels ~[6.9, 25.1)): at pixel columns 9, 18, 23 u is
    ~0.29, 1.27, 1.82. REPEAT reads block columns 0, 0, 1; CLAMP_TO_EDGE 0, 1, 1 (the last
    texels stretched); MIRRORED_REPEAT 0, 1, 0 (the second tile mirrored)."""
    from gspi.data.assets.gltf import CLAMP_TO_EDGE, MIRRORED_REPEAT

    uv = [[0, 0], [2, 0], [0, 1], [2, 1]]
    want = {None: (0, 0, 1), CLAMP_TO_EDGE: (0, 1, 1), MIRRORED_REPEAT: (0, 1, 0)}
    for mode, columns in want.items():
        sampler = None if mode is None else {"wrapS": mode}
        r = front_view(unit_frame_mesh(read_gltf(_feature_quad(tmp_path / f"w{mode}.glb", uv=uv, sampler=sampler))))
        for x, bj in zip((9, 18, 23), columns):
            for y, bi in ((11, 0), (20, 1)):
                np.testing.assert_allclose(r.albedo_srgb[y, x], BLOCKS[bi, bj] / 255, atol=1e-5,
                                           err_msg=f"wrapS={mode} pixel ({y}, {x})")


def test_real_objects_experiment_composes_the_three_methods():
    """+experiment=real_objects: GS-PI, no decomposition and joint IR, reconstructing each object."""
    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR

    from eval.config import register_configs

    register_configs()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("gspi_run", overrides=["data_dir=d", "out=o", "+experiment=real_objects"],
                      return_hydra_config=True)
    assert cfg.hydra.sweeper.params.method == "gspi,no_decomposition,joint_ir"
    assert cfg.assets is None and cfg.table == "table1" and cfg.recon.iterations > 0


BLOCK_CENTRES = {(0, 0): (11, 11), (0, 1): (11, 20), (1, 0): (20, 11), (1, 1): (20, 20)}  # front_view pixels


def test_alpha_mask_cuts_out_below_the_cutoff(tmp_path):
    """alphaMode MASK (glTF 2.0, 3.9.4): a hit is drawn where factor.a x texture.a >= alphaCutoff.
    The fail mark of drawing it opaque: the cut-out blocks in the mask."""
    alpha = [[255, 0], [100, 200]]              # 1, 0, 0.39, 0.78
    cases = {"OPAQUE": ({}, {(0, 0), (0, 1), (1, 0), (1, 1)}),            # alpha ignored
             "MASK 0.5": ({"alphaMode": "MASK"}, {(0, 0), (1, 1)}),        # the default cutoff
             "MASK 0.3": ({"alphaMode": "MASK", "alphaCutoff": 0.3}, {(0, 0), (1, 0), (1, 1)}),
             "MASK factor 0.6": ({"alphaMode": "MASK", "pbrMetallicRoughness": {
                 "baseColorTexture": {"index": 0}, "metallicFactor": 0.0,
                 "baseColorFactor": [1, 1, 1, 0.6]}}, {(0, 0)})}               # 0.6, 0, 0.24, 0.47
    for name, (material, kept) in cases.items():
        r = front_view(unit_frame_mesh(read_gltf(_feature_quad(tmp_path / "a.glb", alpha=alpha, material=material))))
        for block, (y, x) in BLOCK_CENTRES.items():
            assert r.mask[y, x] == (block in kept), f"{name}: block {block}"
        if kept:  # what shows through a cut-out block is background, the kept ones keep their colour
            np.testing.assert_allclose(r.albedo_srgb[11, 11], BLOCKS[0, 0] / 255, atol=1e-5)


def test_cut_out_rays_go_on_to_the_surface_behind(tmp_path):
    """A ray through a cut-out texel hits what lies behind it (a second, opaque quad)."""
    front = read_gltf(_feature_quad(tmp_path / "f.glb", alpha=[[255, 0], [0, 255]], material={"alphaMode": "MASK"}))
    back = read_gltf(_feature_quad(tmp_path / "b.glb", material={"pbrMetallicRoughness": {
        "baseColorFactor": [0.0, 0.0, 1.0, 1.0], "metallicFactor": 0.0}}))
    for prim in back.primitives:  # 0.5 behind the first (world +y, away from the camera)
        prim.vertices = prim.vertices + np.array([0.0, 0.5, 0.0])
    front.primitives += back.primitives
    r = front_view(unit_frame_mesh(front), size=32)
    assert r.mask.sum() > 0.5 * 32 * 32 * 0.25
    np.testing.assert_allclose(r.albedo_srgb[11, 11], BLOCKS[0, 0] / 255, atol=1e-5)   # kept texel
    np.testing.assert_allclose(r.albedo_srgb[12, 19], [0.0, 0.0, 1.0], atol=1e-5)      # behind the hole
    assert r.depth[12, 19, 0] > r.depth[11, 11, 0] + 0.1


def test_single_sided_faces_are_culled_from_behind(tmp_path):
    """doubleSided false (the glTF default): seen from behind the quad is not drawn; true: it is."""
    K, size = intrinsics_from_fov(45.0, 32, 32), 32
    behind = look_at_w2c(np.array([0.0, 3.0, 0.0]))
    for sided, drawn in (({}, False), ({"doubleSided": True}, True)):
        mesh = unit_frame_mesh(read_gltf(_feature_quad(tmp_path / "q.glb", material=sided)))
        r = render_mesh_views(mesh, [(K, behind, 0)], size, size, env=torch.ones(8, 16, 3), supersample=2)[0]
        assert bool(r.mask[16, 16]) == drawn and (r.mask.sum() > 100) == drawn
        assert front_view(mesh).mask[16, 16]  # the front is drawn either way


def test_blend_pixels_in_the_outside_brdf_map_and_excluded_on_request(tmp_path):
    from eval.config import ProtocolConfig
    from eval.scored_view import scored_mask
    from omegaconf import OmegaConf

    opaque = front_view(unit_frame_mesh(read_gltf(_feature_quad(tmp_path / "o.glb"))))
    assert opaque.outside_brdf is None
    r = front_view(unit_frame_mesh(read_gltf(_feature_quad(tmp_path / "b.glb", material={
        "alphaMode": "BLEND", "doubleSided": True}))))
    assert r.outside_brdf is not None and (r.outside_brdf >= r.mask).all() and r.mask.any()
    protocol = OmegaConf.structured(ProtocolConfig)
    mask, outside = torch.from_numpy(r.mask), torch.from_numpy(r.outside_brdf)
    assert torch.equal(scored_mask("v", mask, protocol, outside), mask)  # include: the default
    protocol.outside_brdf = "exclude"
    with pytest.raises(ValueError, match="v: mask empty.*outside_brdf.png"):
        scored_mask("v", mask, protocol, outside)
    half = outside.clone()
    half[:, :16] = False
    assert torch.equal(scored_mask("v", mask, protocol, half), mask & ~half)
    from eval.scored_view import wholly_outside_brdf
    assert wholly_outside_brdf({"mask": mask, "outside_brdf": outside})
    assert not wholly_outside_brdf({"mask": mask, "outside_brdf": half}) and not wholly_outside_brdf({"mask": mask})


def test_sparse_accessors_replace_the_listed_elements(tmp_path):
    """glTF 2.0, 3.6.2.3: sparse values replace the listed elements, over the bufferView's data
    or over zeros when the accessor has none."""
    base = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    idx, val = np.array([2], np.uint16), np.array([[0, 2, 0]], np.float32)
    blob = base.tobytes() + idx.tobytes() + b"\0\0" + val.tobytes()
    sparse = {"count": 1, "indices": {"bufferView": 1, "componentType": 5123},
              "values": {"bufferView": 2}}
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "buffers": [{"byteLength": len(blob)}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
                           {"buffer": 0, "byteOffset": 36, "byteLength": 2},
                           {"buffer": 0, "byteOffset": 40, "byteLength": 12}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "sparse": sparse}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}]}
    (tmp_path / "sparse.glb").write_bytes(_glb(doc, blob))
    y_up = read_gltf(tmp_path / "sparse.glb").primitives[0].vertices  # Z-up: (x, -z, y)
    np.testing.assert_allclose(y_up, [[0, 0, 0], [1, 0, 0], [0, 0, 2]])
    del doc["accessors"][0]["bufferView"]
    (tmp_path / "zeros.glb").write_bytes(_glb(doc, blob))
    np.testing.assert_allclose(read_gltf(tmp_path / "zeros.glb").primitives[0].vertices,
                               [[0, 0, 0], [0, 0, 0], [0, 0, 2]])
    sparse["indices"]["byteOffset"] = 0
    sparse["values"] = {"bufferView": 0}  # index 7 of 3 elements
    doc["bufferViews"][1] = {"buffer": 0, "byteOffset": 36, "byteLength": 2}
    blob = base.tobytes() + np.array([7], np.uint16).tobytes() + b"\0\0" + val.tobytes()
    (tmp_path / "bad.glb").write_bytes(_glb(doc, blob))
    with pytest.raises(GLTFError, match="bad.glb: accessors\\[0\\]: sparse indices out of range"):
        read_gltf(tmp_path / "bad.glb")


def test_held_out_views_that_see_nothing_of_a_single_sided_asset_are_not_scored(tmp_path):
    """A single-sided quad seen from behind is culled: such test views get gt_channels [] in
    scene.json and the evaluator skips them (it would refuse an empty mask); the others score."""
    from gspi.cli.data import run
    from eval.scored_view import EnvironmentCache, scene_scored_views
    from eval.config import ProtocolConfig

    (tmp_path / "src").mkdir()
    _feature_quad(tmp_path / "src" / "card.glb")
    run(_tiny_import_cfg(tmp_path, tmp_path / "src", num_test_views=8))
    scene = read_scene(tmp_path / "out" / "card")
    empty = {v.id for v in scene.views["test"]
             if not (read_view_file(scene.view_dir("test", v.id), "mask.png") > 0.5).any()}
    assert 0 < len(empty) < 8  # the test views are spread over the hemisphere, the card faces one side
    assert {v.id for v in scene.views["test"] if v.gt_channels == ()} == empty
    scored, _ = scene_scored_views(scene, scene.root, OmegaConf.structured(ProtocolConfig), EnvironmentCache())
    assert {sv.view for sv in scored} == {v.id for v in scene.views["test"]} - empty
    # the run's figure of a scene whose chosen view shows nothing takes the next scored view
    # (it raised "not enough values to unpack" on SimpleSparseAccessor and TextureTransformTest)
    from eval.report_site.run_figure import scene_figure

    ids = [v.id for v in scene.views["test"]]
    first_empty = min(ids.index(e) for e in empty)
    assert any(i not in empty for i in ids[first_empty:])  # the seeded views: t00-t03 empty, t04- seen
    fig = scene_figure(scene, scene.root, tmp_path / "fig.png", OmegaConf.structured(ProtocolConfig),
                       view_index=first_empty)
    assert fig.is_file() and fig.stat().st_size > 1000
    with pytest.raises(ValueError, match="no scored test view"):  # nothing from there on
        scene_figure(scene, scene.root, tmp_path / "none.png", OmegaConf.structured(ProtocolConfig),
                     view_index=len(ids))


def _wrapped_in_scaled_node(src: Path, dst: Path, scale: list[float]) -> Path:
    """`src` GLB with its scene's roots under one new node of the given scale (an asset authored
    in small units and scaled to metres, as product models are)."""
    from gspi.data.assets.gltf import _split_glb

    doc, binary = _split_glb(src, src.read_bytes())
    roots = doc["scenes"][doc.get("scene", 0)]["nodes"]
    doc["nodes"].append({"scale": scale, "children": roots})
    doc["scenes"][doc.get("scene", 0)]["nodes"] = [len(doc["nodes"]) - 1]
    dst.write_bytes(_glb(doc, binary or b""))
    return dst


@pytest.mark.parametrize("scale", [1e-5, 1e-4, 1e4])
def test_an_asset_in_small_or_large_units_imports_with_the_unscaled_gt(tmp_path, scale):
    """The degenerate-node test is relative to the transform's own scale (issue 41): a uniform
    1e-4 (det 1e-12) is not 'scaled to 0', and after the unit frame the GT maps equal the
    unscaled asset's."""
    src = quad_glb(tmp_path / "quad.glb")
    ref = front_view(unit_frame_mesh(read_gltf(src)))
    asset = read_gltf(_wrapped_in_scaled_node(src, tmp_path / "scaled.glb", [scale] * 3))
    assert not any("degenerate" in s for s in asset.ignored)
    got = front_view(unit_frame_mesh(asset))
    assert (got.mask == ref.mask).all()
    for name in ("albedo_srgb", "roughness", "metallic", "normal", "depth"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), atol=1e-5, err_msg=name)


def test_a_node_flattened_on_one_axis_is_still_named(tmp_path):
    from gspi.data.assets.gltf import is_degenerate

    src = quad_glb(tmp_path / "quad.glb")
    with pytest.raises(GLTFError, match="flat.glb.*no triangle primitives"):
        read_gltf(_wrapped_in_scaled_node(src, tmp_path / "flat.glb", [1e-4, 0.0, 1e-4]))
    assert is_degenerate(np.diag([1e-4, 1e-4, 0.0])) and not is_degenerate(np.diag([1e-4] * 3))
    assert is_degenerate(np.diag([1.0, 1.0, 1e-12])) and is_degenerate(np.zeros((3, 3)))


def test_a_file_that_is_not_a_glb_writes_nothing_and_fails_in_one_line(tmp_path):
    """It left an empty, valid-looking splits.json (and out/.hydra) and exited 1."""
    from gspi.cli.data import main
    from tests.reliability.helpers import run_cli

    (tmp_path / "chair.glb").write_bytes(b"not a gltf file at all")
    out = tmp_path / "data"
    code, text = run_cli(main, [f"import.glb={tmp_path / 'chair.glb'}", f"out={out}", "preset=tiny"])
    lines = [line for line in text.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, text
    assert str(tmp_path / "chair.glb") in lines[0] and "nothing written" in lines[0]
    assert not out.exists(), sorted(out.rglob("*"))
