"""Importing each external system's outputs (baselines/<system>.py) into the canonical layout.

Each test writes a fixture folder in the system's real output layout from the known canonical
maps of a tiny sphere scene (8-bit PNGs written like torchvision's save_image: round half up,
grey maps as 3 equal channels), imports it, and compares with expected maps computed here
independently (own sRGB formulas), exactly up to the 16-bit rounding of the canonical PNGs.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from baselines.adapter import AdapterError, get_adapter, load_method_config
from eval.common.layout import read_meta, read_scene, read_view_file
from tests.adapter_fixtures import gt_maps, q8, save_image, srgb_eotf, srgb_oetf, write_gs_ir
from tests.fixtures import make_scene

Q16 = 0.5 / 65535 + 1e-7  # canonical PNGs round to the nearest 16-bit step


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene(tmp_path_factory.mktemp("gt"), "ball", size=20, seed=1, num_test=3)


def import_and_compare(system, src, scene, tmp_path, expected, cfg_overrides=None):
    cfg = {**load_method_config(system), **(cfg_overrides or {})}
    pred = get_adapter(system).import_outputs(src, scene.root, tmp_path / "pred", cfg)
    assert pred == tmp_path / "pred" / scene.name
    for view, maps in zip(scene.split_views("test"), expected):
        vdir = pred / "test" / view.id
        present = {p.stem for p in vdir.glob("*.png")} - {"alpha"}  # the system's opacity, not a map
        assert present == set(maps), (system, present)
        for channel, want in maps.items():
            got = read_view_file(vdir, f"{channel}.png").astype(np.float64)
            want = want if channel == "albedo" else want[..., None]
            np.testing.assert_allclose(got, want, rtol=0, atol=Q16, err_msg=f"{system} {channel}")
    return pred


# ----------------------------------------------------------------------------- GS-IR

@pytest.mark.parametrize("gamma,metallic", [(True, False), (False, True)])
def test_gs_ir_panels_colour_space_and_remap(scene, tmp_path, gamma, metallic):
    maps = gt_maps(scene)
    src = write_gs_ir(tmp_path / "model", maps, gamma=gamma)
    expected = []
    for m in maps:
        albedo = srgb_oetf(q8(srgb_eotf(m["albedo"]))) if gamma else q8(m["albedo"])
        e = {"albedo": albedo, "roughness": 0.04 + 0.96 * q8((m["roughness"] - 0.04) / 0.96)}
        if metallic:
            e["metallic"] = q8(m["metallic"])
        expected.append(e)
    pred = import_and_compare("gs_ir", src, scene, tmp_path, expected,
                              {"gamma": gamma, "metallic": metallic})
    meta = read_meta(pred)
    assert meta["method"] == "gs_ir" and meta["runtime_s"] == {"material": None, "end_to_end": None}


def test_gs_ir_errors_name_what_is_missing(scene, tmp_path):
    maps = gt_maps(scene)
    src = write_gs_ir(tmp_path / "model", maps)
    cfg = load_method_config("gs_ir")
    adapter = get_adapter("gs_ir")
    (src / "test" / "ours_None" / "pbr" / "00002_brdf.png").unlink()
    with pytest.raises(AdapterError, match=r"00002_brdf\.png: missing .*test view 2 \(002\)"):
        adapter.import_outputs(src, scene.root, tmp_path / "pred", cfg)
    # a width that is not 3 panels, and a roughness panel that is not grey
    save_image(src / "test" / "ours_None" / "pbr" / "00002_brdf.png", np.zeros((20, 50, 3)))
    with pytest.raises(AdapterError, match="not 3 equal panels"):
        adapter.import_outputs(src, scene.root, tmp_path / "pred", cfg)
    bad = np.zeros((20, 60, 3))
    bad[:, 20:40, 0] = 0.5
    save_image(src / "test" / "ours_None" / "pbr" / "00002_brdf.png", bad)
    with pytest.raises(AdapterError, match="grey map"):
        adapter.import_outputs(src, scene.root, tmp_path / "pred", cfg)
    with pytest.raises(AdapterError, match=r"ours_None.*missing folder"):
        adapter.import_outputs(tmp_path, scene.root, tmp_path / "pred", cfg)


def test_wrong_resolution_is_an_error(scene, tmp_path):
    half = [{k: v[::2, ::2] for k, v in m.items()} for m in gt_maps(scene)]
    src = write_gs_ir(tmp_path / "model", half)
    with pytest.raises(AdapterError, match=r"albedo map has shape \(10, 10, 3\), expected \(20, 20, 3\)"):
        get_adapter("gs_ir").import_outputs(src, scene.root, tmp_path / "pred",
                                            load_method_config("gs_ir"))


# ----------------------------------------------------------------------------- R3DG

def test_r3dg_base_color_is_srgb_highest_iteration_wins(scene, tmp_path):
    maps = gt_maps(scene)
    for it, scale in ((30000, 0.5), (40000, 1.0)):  # a stale earlier export must be ignored
        test = tmp_path / "model" / "neilf" / "test" / f"ours_{it}"
        for k, m in enumerate(maps):
            save_image(test / "base_color" / f"{k:05d}.png", scale * m["albedo"])
            save_image(test / "roughness" / f"{k:05d}.png", scale * m["roughness"])
            save_image(test / "normal" / f"{k:05d}.png", m["albedo"])
    expected = [{"albedo": q8(m["albedo"]), "roughness": q8(m["roughness"])} for m in maps]
    import_and_compare("r3dg", tmp_path / "model", scene, tmp_path, expected)
    # the neilf folder itself is accepted as src too; a missing roughness map is named
    (tmp_path / "model" / "neilf" / "test" / "ours_40000" / "roughness" / "00001.png").unlink()
    with pytest.raises(AdapterError, match=r"roughness/00001\.png: missing"):
        get_adapter("r3dg").import_outputs(tmp_path / "model" / "neilf", scene.root,
                                           tmp_path / "p2", load_method_config("r3dg"))


# ----------------------------------------------------------------------------- GaussianShader

def test_gaussianshader_diffuse_color_display_space(scene, tmp_path):
    maps = gt_maps(scene)
    test = tmp_path / "model" / "test" / "ours_30000"
    for k, m in enumerate(maps):
        save_image(test / "diffuse_color" / f"{k:05d}.png", m["albedo"])
        save_image(test / "diffuse" / f"{k:05d}.png", 1 - m["albedo"])
        save_image(test / "roughness" / f"{k:05d}.png", m["roughness"])
        save_image(test / "specular" / f"{k:05d}.png", m["albedo"])
    expected = [{"albedo": q8(m["albedo"]), "roughness": q8(m["roughness"])} for m in maps]
    import_and_compare("gaussianshader", tmp_path / "model", scene, tmp_path, expected)
    raw = [{"albedo": q8(1 - m["albedo"]), "roughness": q8(m["roughness"])} for m in maps]
    import_and_compare("gaussianshader", tmp_path / "model", scene, tmp_path / "raw", raw,
                       {"albedo_source": "diffuse"})
    with pytest.raises(ValueError, match="allowed: diffuse_color, diffuse"):
        get_adapter("gaussianshader").import_outputs(
            tmp_path / "model", scene.root, tmp_path / "p3",
            {**load_method_config("gaussianshader"), "albedo_source": "specular"})


# ----------------------------------------------------------------------------- IRGS

def test_irgs_linear_base_color_is_encoded(scene, tmp_path):
    maps = gt_maps(scene)
    test = tmp_path / "model" / "irgs" / "test" / "ours_20000"
    for k, m in enumerate(maps):
        save_image(test / "base_color_linear" / f"{k:05d}.png", srgb_eotf(m["albedo"]))
        save_image(test / "base_color" / f"{k:05d}.png", m["albedo"])
        save_image(test / "roughness" / f"{k:05d}.png", m["roughness"])
        save_image(test / "rend_alpha" / f"{k:05d}.png", m["roughness"] > 0)
    expected = [{"albedo": srgb_oetf(q8(srgb_eotf(m["albedo"]))), "roughness": q8(m["roughness"])}
                for m in maps]
    pred = import_and_compare("irgs", tmp_path / "model", scene, tmp_path, expected)
    for k, (view, m) in enumerate(zip(scene.split_views("test"), maps)):  # rend_alpha -> alpha.png
        np.testing.assert_array_equal(read_view_file(pred / "test" / view.id, "alpha.png")[..., 0],
                                      (m["roughness"] > 0).astype(np.float32))
    srgb = [{"albedo": q8(m["albedo"]), "roughness": q8(m["roughness"])} for m in maps]
    import_and_compare("irgs", tmp_path / "model" / "irgs", scene, tmp_path / "s", srgb,
                       {"albedo_source": "base_color"})
    (tmp_path / "empty").mkdir()
    with pytest.raises(AdapterError, match=r"empty/irgs/test, .*empty/test exists"):
        get_adapter("irgs").import_outputs(tmp_path / "empty", scene.root, tmp_path / "p4",
                                           load_method_config("irgs"))
    with pytest.raises(AdapterError, match=r"nothing: output folder of irgs not found"):
        get_adapter("irgs").import_outputs(tmp_path / "nothing", scene.root, tmp_path / "p4",
                                           load_method_config("irgs"))


# ----------------------------------------------------------------------------- LumiGauss

def test_lumigauss_right_panel_gamma22(scene, tmp_path):
    maps = gt_maps(scene)
    renders = tmp_path / "model" / "render_test" / "ours_40000" / "renders"
    views = scene.split_views("test")
    for m, v in reversed(list(zip(maps, views))):  # named by image: order must not matter
        gt_photo = np.full_like(m["albedo"], 0.3)
        g22 = srgb_eotf(m["albedo"]) ** (1 / 2.2)
        save_image(renders / f"test_{v.id}.png_albedo.png", np.concatenate([gt_photo, g22], 1))
        save_image(renders / f"test_{v.id}.png_normals_world.png", gt_photo)
    expected = [{"albedo": srgb_oetf(q8(srgb_eotf(m["albedo"]) ** (1 / 2.2)) ** 2.2)} for m in maps]
    import_and_compare("lumigauss", tmp_path / "model", scene, tmp_path, expected)
    (renders / f"test_{views[0].id}.png_albedo.png").unlink()
    with pytest.raises(AdapterError, match=r"test_000\.png_albedo\.png: missing"):
        get_adapter("lumigauss").import_outputs(tmp_path / "model", scene.root, tmp_path / "p5",
                                                load_method_config("lumigauss"))


# ----------------------------------------------------------------------------- runtime

def test_runtime_from_argument_config_or_timed_run(scene, tmp_path):
    maps = gt_maps(scene)
    src = write_gs_ir(tmp_path / "model", maps)
    adapter, cfg = get_adapter("gs_ir"), load_method_config("gs_ir")
    (src / "gspi_runtime.json").write_text(json.dumps({"seconds": 42.5}))
    for kwargs, cfg_runtime, want in (({"runtime_s": 7.0}, 9.0, 7.0), ({}, 9.0, 9.0),
                                      ({}, None, 42.5)):
        pred = adapter.import_outputs(src, scene.root, tmp_path / "pred",
                                      {**cfg, "runtime_s": cfg_runtime}, **kwargs)
        # one number is a total: the material time is not separable from it ("total only")
        assert read_meta(pred)["runtime_s"] == {"material": None, "end_to_end": want}
    pred = adapter.import_outputs(src, scene.root, tmp_path / "pred",
                                  {**cfg, "runtime_s": {"geometry": 30.0, "material": 12.5}})
    assert read_meta(pred)["runtime_s"] == {"material": 12.5, "end_to_end": 42.5, "geometry": 30.0}


def test_unknown_system_lists_the_allowed_ones():
    with pytest.raises(ValueError, match="gaussianshader, gs_ir, irgs, lumigauss, materialanything, r3dg"):
        get_adapter("nerfactor")
    assert read_scene  # the canonical reader is the one the adapters use
