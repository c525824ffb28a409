"""Path-traced input views (gspi.data.assets.pathtrace): environment orientation, camera and image
orientation against the exact renderers, and a tiny pathtraced dataset whose GT is unchanged."""
from __future__ import annotations


import numpy as np
import pytest
import torch

pytest.importorskip("mitsuba")

from eval.envmap import latlong_directions, sample_latlong  # noqa: E402
from eval.common.layout import read_scene  # noqa: E402
from eval.relight import prefilter_environment  # noqa: E402
from gspi.data.environments import make_environment  # noqa: E402
from gspi.data.generate import BenchmarkConfig, generate_dataset, scene_recipes  # noqa: E402
from gspi.data.lattice import intrinsics_from_fov, look_at_w2c  # noqa: E402
from gspi.data.assets.pathtrace import PathTraceConfig, _mitsuba, mitsuba_scene, retracer, \
    sensor  # noqa: E402
from gspi.data.procedural.render_scene import scene_views, sdf_renderer  # noqa: E402


def test_envmap_orientation_matches_the_project_convention():
    """A camera looking along d sees the environment's value at d (eval.envmap convention)."""
    mi = _mitsuba()
    d = latlong_directions(32, 64)
    env = (d.clamp_min(0) * torch.tensor([1.0, 2.0, 4.0]) + 0.05).numpy()  # +x red, +y green
    scene = mitsuba_scene([], env, PathTraceConfig(), hide_emitters=False)
    for target in ([1, 0, 0.1], [0, 1, 0.1], [-1, 0.2, 0.1], [0, -1, 0.3], [0.3, 0.1, 1.0]):
        t = np.array(target, float) / np.linalg.norm(target)
        up = np.array([0, 0, 1.0]) if abs(t[2]) < 0.9 else np.array([0, 1.0, 0])
        img = np.array(mi.render(scene, sensor=sensor(intrinsics_from_fov(2.0, 4, 4),
                                                      look_at_w2c(np.zeros(3), t, up), 4, 4, 16),
                                 spp=16))
        want = sample_latlong(torch.from_numpy(env), torch.tensor(t, dtype=torch.float32))
        np.testing.assert_allclose(img.mean((0, 1)), want.numpy(), rtol=0.1, atol=0.01)


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def test_pathtraced_views_line_up_with_the_exact_renderer():
    """Same silhouette and shading layout as the split-sum render of the same camera (an
    upside-down or mirrored image would not be), similar brightness."""
    recipe = next(r for r in scene_recipes(0, BenchmarkConfig(num_train_scenes=3, num_val_scenes=0,
                                                                num_test_scenes=0))
                  if r["family"] == "multipart")
    lattice = {"num_views": 2, "radius": 3.0, "fov_deg": 45.0, "min_elevation_deg": 0.0}
    views = scene_views(recipe, width=32, height=32, lattice=lattice)
    cams = [(v.K, v.w2c, 1) for v in views["train"]]
    env = make_environment("overcast", 16)  # no sun: 8 spp are enough to compare layouts
    exact = sdf_renderer(recipe)(cams, 32, 32, prefilter_environment(env), 2)
    traced = retracer("pathtraced", {"spp": 8, "mesh_resolution": 64}, recipe=recipe)(
        cams, 32, 32, env)
    for r, p in zip(exact, traced):
        covered = p.max(-1) > 1e-6
        assert (covered & r.mask).sum() / (covered | r.mask).sum() > 0.8
        lum_s, lum_p = r.rgb.mean(-1), p.mean(-1)
        c = _corr(lum_s, lum_p)
        assert c > 0.8 and c > _corr(lum_s, lum_p[::-1]) and c > _corr(lum_s, lum_p[:, ::-1])
        assert 0.7 < lum_p[r.mask].mean() / lum_s[r.mask].mean() < 1.3


def test_glb_textures_reach_mitsuba_upright(tmp_path):
    from gspi.data.assets.gltf import read_gltf
    from gspi.data.assets.mesh_render import render_mesh_views, unit_frame_mesh
    from tests.gltf_fixtures import quad_glb

    mesh = unit_frame_mesh(read_gltf(quad_glb(tmp_path / "quad.glb")))
    cams = [(intrinsics_from_fov(45.0, 32, 32), look_at_w2c(np.array([0.0, -3.0, 0.0])), 0)]
    env = torch.ones(8, 16, 3)
    exact = render_mesh_views(mesh, cams, 32, 32, env=env, supersample=2)[0]
    traced = retracer("pathtraced", {"spp": 16}, mesh=mesh)(cams, 32, 32, env)[0]
    for y, x in ((11, 11), (11, 20), (20, 11), (20, 20)):  # block centres (test_data_glb)
        patch_s, patch_p = exact.rgb[y - 1:y + 2, x - 1:x + 2], traced[y - 1:y + 2, x - 1:x + 2]
        # Same dominant channel per block: the texture is not flipped or mirrored.
        assert np.argmax(patch_s.mean((0, 1))) == np.argmax(patch_p.mean((0, 1)))
    assert _corr(exact.rgb[exact.mask], traced[exact.mask]) > 0.8


def _tiny(renderer: str, relit_renderer: str = "splitsum") -> BenchmarkConfig:
    return BenchmarkConfig(num_train_scenes=0, num_val_scenes=0, num_test_scenes=1, image_size=16,
                           env_height=16, num_test_views=1, num_val_views=0, num_relight_envs=1,
                           point_clouds=False, contact_sheets=False, renderer=renderer,
                           relit_renderer=relit_renderer,
                           pathtrace={"spp": 4, "mesh_resolution": 48},
                           lattice={"num_views": 2, "radius": 3.0, "fov_deg": 45.0,
                                    "min_elevation_deg": 0.0})


def test_pathtraced_dataset_keeps_the_ground_truth(tmp_path):
    a = generate_dataset(tmp_path / "split", _tiny("splitsum"), seed=0)
    b = generate_dataset(tmp_path / "path", _tiny("pathtraced"), seed=0)
    name = a["scenes"][0]["name"]
    assert b["scenes"][0]["retrace_seconds"] > 0
    sa, sb = read_scene(tmp_path / "split" / name), read_scene(tmp_path / "path" / name)
    assert sb.extra["generator"]["renderer"] == "pathtraced"
    for split, vid in (("train", "000"), ("test", "t00")):
        da, db = sa.view_dir(split, vid), sb.view_dir(split, vid)
        for f in ("albedo.png", "roughness.png", "metallic.png", "normal.exr", "depth.exr",
                  "mask.png"):
            assert (da / f).read_bytes() == (db / f).read_bytes(), f
        assert (da / "rgb.exr").read_bytes() != (db / "rgb.exr").read_bytes()
    relit = f"relit_{sa.relight_envs[0]}.exr"
    assert (sa.view_dir("test", "t00") / relit).read_bytes() == \
        (sb.view_dir("test", "t00") / relit).read_bytes()


def test_unknown_renderer_is_an_error():
    with pytest.raises(ValueError, match="raytraced"):
        retracer("raytraced", {})
    with pytest.raises(ValueError, match="data.relit_renderer must be splitsum or pathtraced"):
        retracer("raytraced", {}, key="data.relit_renderer")
    assert retracer("splitsum", {}) is None


def test_pathtraced_relit_ground_truth_and_the_stored_reference(tmp_path):
    """data.relit_renderer=pathtraced replaces only the relit GT images (inputs and maps are
    byte-identical); eval.relight.reference=stored scores against those files, and on a
    split-sum dataset the stored reference equals the shaded one."""
    from omegaconf import OmegaConf

    from eval.config import ProtocolConfig
    from eval.common.layout import LayoutError
    from eval.scored_view import EnvironmentCache, load_gt_view, load_stored_relit, relit_pairs

    generate_dataset(tmp_path / "split", _tiny("splitsum"), seed=0)
    b = generate_dataset(tmp_path / "path", _tiny("splitsum", "pathtraced"), seed=0)
    name = b["scenes"][0]["name"]
    sa, sb = read_scene(tmp_path / "split" / name), read_scene(tmp_path / "path" / name)
    assert sb.extra["generator"]["relit_renderer"] == "pathtraced"
    assert "relit_renderer" not in sa.extra["generator"]  # the default is not recorded (byte-identity)
    da, db = sa.view_dir("test", "t00"), sb.view_dir("test", "t00")
    for f in ("rgb.exr", "albedo.png", "roughness.png", "metallic.png", "normal.exr", "mask.png"):
        assert (da / f).read_bytes() == (db / f).read_bytes(), f
    env = sa.relight_envs[0]
    assert (da / f"relit_{env}.exr").read_bytes() != (db / f"relit_{env}.exr").read_bytes()

    protocol = OmegaConf.structured(ProtocolConfig)
    stored = OmegaConf.structured(ProtocolConfig)
    stored.relight.reference = "stored"
    envs = EnvironmentCache()
    for scene in (sa, sb):
        view = scene.split_views("test")[0]
        g = load_gt_view(scene, view)
        relit = load_stored_relit(scene, view, scene.relight_envs)
        p = {c: g[c] for c in ("albedo", "roughness", "metallic")}
        scale = torch.ones(3, dtype=torch.float64)
        shaded = relit_pairs(scene, g, p, g["albedo"], scale, g["mask"], protocol, envs, view)[env]
        read = relit_pairs(scene, g, p, g["albedo"], scale, g["mask"], stored, envs, view)[env]
        torch.testing.assert_close(read.gt_linear.float(), relit[env].float())
        if scene is sa:
            torch.testing.assert_close(read.gt_linear.float(), shaded.gt_linear.float(), rtol=1e-5, atol=1e-6)
        else:  # shadows, interreflection and Mitsuba's BSDF: a different reference
            assert (read.gt_linear - shaded.gt_linear).abs().max() > 1e-3
    # through the evaluator's path (the GT scene scored as its own prediction)
    from eval.common.imageio import read_exr
    from eval.scored_view import scene_scored_views
    for scene, want_file in ((sa, False), (sb, True)):
        sv = scene_scored_views(scene, scene.root, stored, envs)[0][0]
        sv_shaded = scene_scored_views(scene, scene.root, protocol, envs)[0][0]
        stored_img = torch.from_numpy(read_exr(scene.view_dir("test", sv.view) / f"relit_{env}.exr"))
        torch.testing.assert_close(sv.relit[env].gt_linear.float(), stored_img)
        assert torch.equal(sv.relit[env].pred_linear, sv_shaded.relit[env].pred_linear)
        assert torch.allclose(sv.relit[env].gt_linear.float(), sv_shaded.relit[env].gt_linear.float(),
                              rtol=1e-5, atol=1e-6) != want_file
    (da / f"relit_{env}.exr").unlink()
    with pytest.raises(LayoutError, match=f"relit_{env}.exr: not found"):
        load_stored_relit(sa, sa.split_views("test")[0], [env])
