"""In-house baselines: no decomposition and joint inverse rendering (baselines/)."""
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from baselines import joint_ir, no_decomposition
from baselines.joint_ir_shading import prefilter_operators, shade
from baselines.joint_ir_weights import compositing_weights
from eval.common.colorspace import linear_to_srgb
from eval.common.imageio import write_exr
from eval.common.layout import LayoutError, read_scene, read_view_file, write_view_file
from eval.common.atomic import write_json_atomic
from eval.relight import split_sum
from eval.views import view_directions
from gspi.gaussians.rasterize import render_gaussians
from gspi.recon.data import ReconInputError
from tests.fixtures import (look_at_w2c, make_dataset, make_envmap, make_scene, surfel_sphere)

CONF = Path(__file__).resolve().parents[1] / "conf" / "method"
Q16 = 0.5 / 65535 + 1e-7  # 16-bit PNG rounding


def _cameras(view):
    return (torch.as_tensor(view.w2c, dtype=torch.float32)[None],
            torch.as_tensor(view.K, dtype=torch.float32)[None])


# ---------------------------------------------------------------- no decomposition
class TestFitConstants:
    def test_means_over_training_foreground(self, tmp_path):
        root = make_dataset(tmp_path, num_scenes=2, size=24)
        write_json_atomic(root / "splits.json", {"train": ["sphere_0", "sphere_1"], "val": [], "test": []})
        # one scene through gt_points.npz (fast path) with values unlike its maps
        np.savez(root / "sphere_1" / "gt_points.npz", roughness=np.array([0.1, 0.3], np.float32),
                 metallic=np.array([1.0, 0.0], np.float32))
        scene = read_scene(root / "sphere_0")
        r, m = [], []
        for v in scene.split_views("train"):
            d = scene.view_dir("train", v.id)
            mask = read_view_file(d, "mask.png")[..., 0] > 0.5
            r += list(read_view_file(d, "roughness.png")[..., 0][mask])
            m += list(read_view_file(d, "metallic.png")[..., 0][mask])
        r += [0.1, 0.3]
        m += [1.0, 0.0]
        got = no_decomposition.fit_constants(root)
        assert got["roughness"] == pytest.approx(np.mean(np.float64(r)), abs=1e-9)
        assert got["metallic"] == pytest.approx(np.mean(np.float64(m)), abs=1e-9)

    def test_no_training_scenes_is_an_error(self, sphere_dataset):
        with pytest.raises(LayoutError, match="splits.json.*no 'train' scenes"):
            no_decomposition.fit_constants(sphere_dataset)


def test_no_decomposition_writes_render_and_constants(tmp_path):
    scene = make_scene(tmp_path / "gt", "s", size=24, num_train=1, num_test=2)
    asset = surfel_sphere(600, color=(0.9, 0.5, 0.1))
    constants = {"roughness": 0.3, "metallic": 0.7}
    stats = no_decomposition.predict_scene(scene, asset, tmp_path / "pred" / "s", {},
                                           constants=constants)
    assert stats["test_views"] == 2 and stats["material_s"] >= 0
    for v in scene.split_views("test"):
        out = render_gaussians(asset, *_cameras(v), 24, 24)
        alpha = out.alpha[0]
        inside = (alpha > 0.004)[..., 0].numpy()
        expected = linear_to_srgb((out.rgb[0] / alpha.clamp_min(1e-8)).clamp(0, 1)).numpy()
        d = tmp_path / "pred" / "s" / "test" / v.id
        assert inside.sum() > 50
        np.testing.assert_allclose(read_view_file(d, "albedo.png")[inside], expected[inside], atol=Q16)
        assert np.all(read_view_file(d, "albedo.png")[~inside] == 0)
        for key, value in constants.items():
            got = read_view_file(d, f"{key}.png")[..., 0]
            np.testing.assert_allclose(got[inside], value, atol=Q16)
            assert np.all(got[~inside] == 0)


# ---------------------------------------------------------------- joint IR: building blocks
def test_shader_equals_eval_split_sum():
    """Same numbers as the evaluator's shader given the raw map (float32 rounding of the
    matrix products vs the FFT filter: observed ~3e-7 relative, bound 1e-5)."""
    g = torch.Generator().manual_seed(0)
    n = 400
    albedo, rough, metal = torch.rand(n, 3, generator=g), torch.rand(n, 1, generator=g), torch.rand(n, 1, generator=g)
    normal = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    view = torch.nn.functional.normalize(normal + 0.8 * torch.randn(n, 3, generator=g), dim=-1)
    env = torch.from_numpy(make_envmap(3, height=8, width=16))  # HDR, with a bright lobe
    ref = split_sum(albedo, rough, metal, normal, view, env)
    env_param = env.clone().requires_grad_(True)
    got = shade(albedo, rough, metal, normal, view, env_param, prefilter_operators(8, 16))
    torch.testing.assert_close(got, ref, rtol=1e-5, atol=1e-5)
    got.sum().backward()
    assert env_param.grad.abs().sum() > 0 and torch.isfinite(env_param.grad).all()


def test_compositing_weights_reproduce_rasterized_features():
    K = torch.tensor([[30.0, 0, 16], [0, 30.0, 16], [0, 0, 1]])
    w2c = torch.as_tensor(look_at_w2c(np.array([2.5, 0.5, 1.0])), dtype=torch.float32)
    asset = surfel_sphere(500)
    weights = compositing_weights(asset, w2c, K, 32, 32, max_elems=1 << 14)  # forces segments
    features = torch.rand(asset.num_gaussians, 4, generator=torch.Generator().manual_seed(1))
    ref = render_gaussians(asset, w2c[None], K[None], 32, 32, features=features).features[0]
    torch.testing.assert_close(weights.to_image(weights.render(features)), ref, atol=1e-5, rtol=1e-5)
    assert weights.pixels.numel() > 100


# ---------------------------------------------------------------- joint IR: end to end
ALBEDO_TRUE = (0.7, 0.3, 0.15)  # linear
SIZE = 24


def _synthetic_scene(root: Path, asset):
    """Sphere scene whose train inputs are ``asset`` rendered with constant known materials
    (albedo ALBEDO_TRUE, roughness 0.5, metallic 0) under the capture env: maps and normals
    by the rasterizer, shading by the evaluator's split-sum, mask = alpha > 0.5."""
    scene = make_scene(root, "syn", size=SIZE, num_train=4, num_test=2)
    env = torch.from_numpy(make_envmap(0))
    write_exr(scene.envmap_path("cap"), env.numpy())
    n = asset.num_gaussians
    features = torch.cat([torch.tensor(ALBEDO_TRUE).expand(n, 3), torch.full((n, 1), 0.5),
                          torch.zeros(n, 1)], dim=-1)
    for v in scene.split_views("train"):
        out = render_gaussians(asset, *_cameras(v), SIZE, SIZE, features=features)
        alpha = out.alpha[0].clamp_min(1e-8)
        maps = out.features[0] / alpha
        rgb = alpha * split_sum(maps[..., :3], maps[..., 3:4], maps[..., 4:5], out.normals_unit[0],
                                view_directions(v.K, v.w2c, SIZE, SIZE), env)
        d = scene.view_dir("train", v.id)
        write_view_file(d, "rgb.exr", rgb.numpy())
        write_view_file(d, "mask.png", (out.alpha[0] > 0.5).float().numpy())
    return scene


def test_joint_ir_reduces_loss_and_moves_albedo_to_truth(tmp_path):
    asset = surfel_sphere(600)
    scene = _synthetic_scene(tmp_path, asset)
    views = joint_ir.load_scene_views(scene, "train")
    # Light colour and albedo colour are ambiguous (a tinted sky explains a tinted object as
    # well as a white one); nvdiffrec's white-light prior is what moves the albedo colour.
    cfg = joint_ir.JointIRConfig(iterations=40, views_per_iteration=2, env_height=8,
                                 lr_albedo=0.05, lambda_env_white=0.1)
    fitted, env, stats = joint_ir.fit_materials(asset, views, cfg)
    assert stats["loss_final"] < 0.5 * stats["loss_first"]  # observed ~0.23x
    seen = torch.zeros(asset.num_gaussians, dtype=torch.bool)
    for i in range(views.num_views):
        w = compositing_weights(asset, views.viewmats[i], views.Ks[i], SIZE, SIZE)
        seen |= w.matrix_t.crow_indices().diff() > 0
    truth = torch.tensor(ALBEDO_TRUE)
    err_init = (torch.full((3,), cfg.init_albedo) - truth).abs().mean()
    err = (fitted.albedo[seen].mean(0) - truth).abs().mean()
    assert err < 0.5 * err_init  # observed 0.08 vs 0.25
    assert env.shape == (8, 16, 3) and torch.isfinite(env).all()


def test_joint_ir_leaves_out_views_without_foreground(tmp_path):
    """A view with an empty mask (a single-sided asset seen from behind) has no loss; with it in
    a batch the masked means were NaN and the fit diverged. It is left out; with none left, one
    stated error."""
    asset = surfel_sphere(300)
    views = joint_ir.load_scene_views(_synthetic_scene(tmp_path, asset), "train")
    views.masks[:2] = False
    cfg = joint_ir.JointIRConfig(iterations=4, views_per_iteration=2, env_height=8)
    assert len(joint_ir._prepare_views(asset, views, cfg)) == views.num_views - 2
    fitted, env, stats = joint_ir.fit_materials(asset, views, cfg)
    assert np.isfinite(stats["loss_final"]) and torch.isfinite(fitted.albedo).all()
    views.masks[:] = False
    with pytest.raises(ValueError, match="no input view has a foreground pixel"):
        joint_ir._prepare_views(asset, views, cfg)


def test_joint_ir_predict_scene_writes_every_test_view(tmp_path):
    asset = surfel_sphere(300)
    scene = _synthetic_scene(tmp_path, asset)
    stats = joint_ir.predict_scene(scene, asset, tmp_path / "pred" / "syn",
                                   {"name": "joint_ir", "_target_": "gspi.run.methods.InhouseMethod", "iterations": 3,
                                    "env_height": 8})
    assert stats["test_views"] == 2 and stats["material_s"] > 0 and stats["iterations"] == 3
    for v in scene.split_views("test"):
        for key in ("albedo", "roughness", "metallic"):
            values = read_view_file(tmp_path / "pred" / "syn" / "test" / v.id, f"{key}.png")
            assert values.shape[:2] == (SIZE, SIZE) and values.max() > 0


def test_joint_ir_missing_mask_names_the_file(tmp_path):
    scene = make_scene(tmp_path, "bad", size=16, num_train=2, num_test=1)
    missing = scene.view_dir("train", "001") / "mask.png"
    missing.unlink()
    with pytest.raises(ReconInputError, match=str(missing).replace(".", r"\.")):
        joint_ir.predict_scene(scene, surfel_sphere(100), tmp_path / "pred",
                               {"iterations": 1, "env_height": 8})


def test_joint_ir_without_train_views_is_an_error(tmp_path):
    scene = make_scene(tmp_path, "empty", size=16, num_train=0, num_test=1)
    with pytest.raises(ReconInputError, match=r"scene\.json: split 'train' has no views"):
        joint_ir.predict_scene(scene, surfel_sphere(100), tmp_path / "pred",
                               {"iterations": 1, "env_height": 8})


# ---------------------------------------------------------------- device (gspi-run device=)
def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*.png"))}


def test_joint_ir_device_auto_writes_the_cpu_files_here(tmp_path):
    """device=auto is the CPU here: the same PNGs, byte for byte, as the default."""
    from gspi.device import resolve_device

    if torch.cuda.is_available():
        pytest.skip("CUDA is present: auto runs there")
    asset = surfel_sphere(200)
    scene = _synthetic_scene(tmp_path, asset)
    cfg = {"iterations": 2, "env_height": 8}
    joint_ir.predict_scene(scene, asset, tmp_path / "cpu", cfg)
    joint_ir.predict_scene(scene, asset, tmp_path / "auto", cfg, device=resolve_device("auto"))
    assert _files(tmp_path / "cpu") == _files(tmp_path / "auto") and len(_files(tmp_path / "cpu")) == 6


class _Reached(Exception):
    pass


def test_joint_ir_optimises_on_the_device_asked_for(tmp_path, monkeypatch):
    """The asset and the input views reach the optimisation on `device` (torch's meta device
    stands in for CUDA), and the prefiltering operators move there once, not at every step."""
    meta = torch.device("meta")
    seen = {}

    def fake_fit(asset, views, cfg, progress=False):
        seen.update(asset=asset.means.device, views={views.images.device, views.masks.device,
                                                     views.viewmats.device, views.Ks.device})
        raise _Reached

    monkeypatch.setattr(joint_ir, "fit_materials", fake_fit)
    scene = make_scene(tmp_path, "s", size=16, num_train=2, num_test=1)
    with pytest.raises(_Reached):
        joint_ir.predict_scene(scene, surfel_sphere(50), tmp_path / "pred", {"env_height": 8}, device=meta)
    assert seen == {"asset": meta, "views": {meta}}
    ops = prefilter_operators(4, 8).to(meta)
    assert {ops.irradiance[0].device, ops.lut.device, *(m.device for m, _ in ops.specular)} == {meta}
    from baselines.joint_ir_shading import prefilter_learnable

    pre = prefilter_learnable(torch.ones(4, 8, 3, device=meta), ops)
    assert {pre.irradiance.device, pre.lut.device, *(m.device for m in pre.specular)} == {meta}


# ---------------------------------------------------------------- configs
def test_method_configs_are_complete_and_known():
    cfg = yaml.safe_load((CONF / "joint_ir.yaml").read_text())
    assert cfg["name"] == "joint_ir" and cfg["_target_"] == "gspi.run.methods.InhouseMethod"
    options = joint_ir.JointIRConfig.from_mapping(cfg)
    assert set(cfg) - {"name", "_target_"} == set(vars(options))  # every option stated in the YAML
    with pytest.raises(ValueError, match=r"unknown joint_ir option\(s\) \['lr'\]"):
        joint_ir.JointIRConfig.from_mapping({"lr": 0.1})
    nd = yaml.safe_load((CONF / "no_decomposition.yaml").read_text())
    assert nd["name"] == "no_decomposition" and nd["_target_"] == "gspi.run.methods.InhouseMethod"
