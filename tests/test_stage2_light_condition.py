"""stage2.data.light_readout (issue 66): the light read-out as Stage II's condition. On a lattice
scene shaded by the split-sum shader under a procedural capture environment: the read-out finds
the sphere's metal part, training and inference build the same condition, a wrong light is told
as such, the light is estimated among the candidates, and a model trains and infers with it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gspi.stage1.extract import unproject_renders
from gspi.stage2.data import PointDataConfig, load_scene_points, local_condition
from gspi.stage2.infer import point_conditions
from gspi.stage2.light_condition import (LIGHT_READOUT_WIDTH, ToldLight, cloud_normals_of, mistold_light,
                                         readout_table, training_light)
from gspi.stage2.light_condition import capture_light
from gspi.stage2.normalize import pbr_from_model
from tests.stage2_fixtures import gt_views_as_renders, make_lattice_scene

ENV = "studio_rgb"
LIGHT = PointDataConfig(light_readout=True, light_env_height=32)


@pytest.fixture(scope="module")
def lit(tmp_path_factory):
    root = make_lattice_scene(tmp_path_factory.mktemp("lit"), "lit_sphere", seed=2, lit=ENV)
    return load_scene_points(root, None), root


def gt_metal(scene) -> np.ndarray:
    return pbr_from_model(torch.from_numpy(scene.f0[:, 4])).numpy() > 0.5


def test_the_readout_finds_the_metal_part(lit):
    scene, _ = lit
    rows = local_condition(scene, np.arange(scene.num_points), scene.xyz, "top_rgb_onehot", light=LIGHT)
    assert rows.shape == (scene.num_points, 35 + LIGHT_READOUT_WIDTH)
    metal = rows[:, 36] > 0.5
    truth = gt_metal(scene)
    iou = np.count_nonzero(metal & truth) / np.count_nonzero(metal | truth)
    assert 0.2 < truth.mean() < 0.8 and iou > 0.9
    assert scene.light_info == {"env": ENV, "rotation_deg": 0.0, "wrong": False}
    # the right light explains the views to a few % (a 32-px view's nearest pixel is not the point's own)
    assert np.median(rows[:, 40]) < -1.0 and rows[0, 41] < -1.0


def test_training_and_inference_build_the_same_condition(lit):
    scene, root = lit
    renders = gt_views_as_renders(root)
    points = unproject_renders(renders, alpha_threshold=0.5)
    normals = cloud_normals_of(points.xyz.astype(np.float64), points.view, scene.cameras)
    light = ToldLight(env=ENV, pre=capture_light(root / "envmaps" / f"{ENV}.exr", 32))
    table = readout_table(renders.rgb, renders.depth, scene.cameras, points.xyz.astype(np.float64), normals, light)
    infer = point_conditions(points, "top_rgb_onehot", renders, light_table=table)
    train = local_condition(scene, np.arange(scene.num_points), scene.xyz, "top_rgb_onehot", light=LIGHT)
    assert infer.shape == train.shape
    close = np.isclose(infer[:, 35:], train[:, 35:], rtol=1e-3, atol=1e-3).all(axis=1)
    assert close.mean() > 0.98  # float32 vs float64 positions: a visibility at its threshold may flip


def test_a_wrong_light_is_told_and_fits_worse(lit):
    scene, root = lit
    capture = capture_light(root / "envmaps" / f"{ENV}.exr", 32)
    others = {"sunset": lambda: capture, ENV: lambda: capture}
    names = [f"s{k}" for k in range(200)]
    assert not any(training_light(n, ENV, capture, others, 0.0).wrong for n in names)
    told = [training_light(n, ENV, capture, others, 0.3) for n in names]
    assert 0.2 < np.mean([t.wrong for t in told]) < 0.4
    assert told == [training_light(n, ENV, capture, others, 0.3) for n in names]  # seeded by name
    assert all(t.wrong and (t.env == "sunset" or 60 <= t.rotation_deg <= 300)
               for t in (training_light(n, ENV, capture, others, 1.0) for n in names))
    turned = ToldLight(env=ENV, pre=capture, rotation_deg=120.0, wrong=True)
    rgb, depth = scene.lattice_linear(), scene.lattice_views()[1]
    normals = cloud_normals_of(scene.xyz, scene.view, scene.cameras)
    right = readout_table(rgb, depth, scene.cameras, scene.xyz, normals, ToldLight(env=ENV, pre=capture))[1]
    wrong = readout_table(rgb, depth, scene.cameras, scene.xyz, normals, turned)[1]
    print("scene residual", right[0, 6], wrong[0, 6])
    assert wrong[0, 6] > right[0, 6] + 0.5  # the scene's residual: three times larger at least


def test_the_scene_level_metal_test_gates_the_condition(lit):
    """light_metal_min_evidence: a scene whose metal evidence passes keeps its rows as read; one
    held to a floor it fails reads every point dielectric, the residual taken over dielectric cells."""
    scene, root = lit
    capture = ToldLight(env=ENV, pre=capture_light(root / "envmaps" / f"{ENV}.exr", 32))
    rgb, depth = scene.lattice_linear(), scene.lattice_views()[1]
    normals = cloud_normals_of(scene.xyz, scene.view, scene.cameras)
    read = lambda floor: readout_table(rgb, depth, scene.cameras, scene.xyz, normals, capture,
                                       metal_min_evidence=floor)[1]
    plain, passes, fails = read(None), read(1.1), read(1e6)
    np.testing.assert_array_equal(passes, plain)  # a half-metal sphere passes the shipped floor
    assert (plain[:, 1] > 0.5).mean() > 0.2
    assert (fails[:, 1] == 0).all()
    assert (fails[:, 5] >= plain[:, 5] - 1e-6).all()  # the best dielectric fit is never better than the best


def test_the_measure_estimates_the_light_among_the_candidates(lit):
    _, root = lit
    scene = load_scene_points(root, None)
    scene.light_source = "estimated"
    local_condition(scene, np.arange(10), scene.xyz[:10], "top_rgb_onehot", light=LIGHT)
    assert scene.light_info["env"] == ENV and scene.light_info["margin"] > 1.5
    assert min(scene.light_info["rotation_deg"], 360 - scene.light_info["rotation_deg"]) <= 10


def test_the_measure_can_tell_a_deliberately_wrong_light(lit):
    """points_measure.told_light (issue 66's guard rail): the estimate turned 90 degrees, or another
    candidate at its turn and gain (seeded by the scene's name), recorded and fitting worse."""
    _, root = lit
    capture = capture_light(root / "envmaps" / f"{ENV}.exr", 32)
    estimate = ToldLight(env=ENV, pre=capture, rotation_deg=300.0, gain=1.5)
    candidates = {ENV: capture, "sunset": capture, "overcast": capture}
    assert mistold_light(estimate, candidates, "s", "estimated") is estimate
    turned = mistold_light(estimate, candidates, "s", "turned90")
    assert (turned.env, turned.rotation_deg, turned.gain, turned.wrong) == (ENV, 30.0, 1.5, True)
    others = {mistold_light(estimate, candidates, f"s{k}", "other").env for k in range(40)}
    assert others == {"sunset", "overcast"}
    assert mistold_light(estimate, candidates, "s7", "other") == mistold_light(estimate, candidates, "s7", "other")
    with pytest.raises(ValueError, match="needs a second candidate light"):
        mistold_light(estimate, {ENV: capture}, "s", "other")
    with pytest.raises(ValueError, match="told_light='rotated': one of estimated, turned90, other"):
        mistold_light(estimate, candidates, "s", "rotated")

    def residual(told: str) -> tuple[float, dict]:
        scene = load_scene_points(root, None)
        scene.light_source, scene.told_light = "estimated", told
        rows = local_condition(scene, np.arange(10), scene.xyz[:10], "top_rgb_onehot", light=LIGHT)
        return float(rows[0, 41]), scene.light_info

    right, info = residual("estimated")
    wrong, wrong_info = residual("turned90")
    assert "told" not in info and wrong_info["told"]["how"] == "turned90"
    assert wrong_info["told"]["rotation_deg"] == pytest.approx((info["rotation_deg"] + 90) % 360)
    assert wrong > right + 0.3  # the scene's log10 residual: twice the right light's at least


def test_config_width_and_checks():
    assert PointDataConfig(light_readout=True).condition_width(0) == 35 + LIGHT_READOUT_WIDTH
    with pytest.raises(ValueError, match="light_wrong_share must lie in"):
        PointDataConfig.from_mapping({"light_wrong_share": 1.5})
    with pytest.raises(ValueError, match="light_metal_min_evidence is a ratio >= 1"):
        PointDataConfig.from_mapping({"light_metal_min_evidence": 0.5})


def test_cloud_normals_are_the_surface_plane_facing_the_camera():
    from gspi.stage2.light_condition import cloud_normals

    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(4000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    camera = np.array([0.0, 0.0, 5.0])
    front = sphere[sphere[:, 2] > 0.3]
    n = cloud_normals(sphere, front, np.broadcast_to(camera, front.shape))
    assert np.degrees(np.arccos(np.clip((n * front).sum(1), -1, 1))).max() < 5.0  # outward, as seen from +z
    back = -front  # the same points seen from the other side face the other way
    n_back = cloud_normals(sphere, back, np.broadcast_to(-camera, back.shape))
    assert np.all((n_back * back).sum(1) > 0.99)


def tiny_readout_model(light: PointDataConfig, metal_gate: bool = False):
    from gspi.stage2.model import RCWConfig, RCWDenoiser

    torch.manual_seed(0)
    return RCWDenoiser(RCWConfig(num_latents=4, latent_dim=16, point_dim=16, num_blocks=1, num_compute_layers=1,
                                 num_heads=2, local_cond_dim=light.condition_width(0), global_token_dim=0,
                                 prediction="x0_readout", readout_column=light.light_readout_column(),
                                 readout_metal_gate=metal_gate))


def test_an_untrained_x0_readout_model_samples_the_readout(lit):
    """x0_readout: the head corrects the read-out and starts at zero, so DDIM returns the read-out."""
    from gspi.stage2.sampler import predict_point_pbr

    scene, _ = lit
    idx = np.arange(0, scene.num_points, 7)
    cond = local_condition(scene, idx, scene.xyz[idx], "top_rgb_onehot", light=LIGHT)
    assert LIGHT.light_readout_column() == 35
    readout = cond[:, [37, 38, 39, 35, 36]].clip(0, 1)  # albedo sRGB, roughness, metallic
    model = tiny_readout_model(LIGHT)
    pbr = predict_point_pbr(model, scene.xyz[idx], cond, None, num_steps=5).numpy()
    np.testing.assert_allclose(pbr, readout, atol=1e-4)
    with torch.no_grad():
        model.out.bias.fill_(0.2)  # a correction moves every channel (metallic 1 clamps)
    moved = predict_point_pbr(model, scene.xyz[idx], cond, None, num_steps=5).numpy()
    assert np.all((moved > readout + 0.05) | (readout > 0.85))


def test_the_metal_gate_adds_no_metal_where_the_readout_rules_it_out(lit):
    """readout_metal_gate: a correction that adds metal everywhere moves only the points whose
    read-out has some; the other channels move everywhere, as without the gate."""
    from gspi.stage2.sampler import predict_point_pbr

    scene, _ = lit
    idx = np.arange(0, scene.num_points, 7)
    cond = local_condition(scene, idx, scene.xyz[idx], "top_rgb_onehot", light=LIGHT)
    cond[::2, 36] = 0.0  # every other point: metal ruled out (the scene-level test zeroes them all)
    cond[1::2, 36] = 0.25
    readout = cond[:, [37, 38, 39, 35, 36]].clip(0, 1)
    gated, plain = tiny_readout_model(LIGHT, metal_gate=True), tiny_readout_model(LIGHT)
    with torch.no_grad():
        for model in (gated, plain):
            model.out.bias.fill_(0.2)
    pbr = predict_point_pbr(gated, scene.xyz[idx], cond, None, num_steps=5).numpy()
    np.testing.assert_allclose(pbr[::2, 4], 0.0, atol=1e-6)  # the DDIM eps round trip
    assert np.all(pbr[1::2, 4] > 0.3)  # 0.25 + 0.2 / 2 (model space spans [-1, 1])
    np.testing.assert_allclose(pbr[:, :4], predict_point_pbr(plain, scene.xyz[idx], cond, None, num_steps=5).numpy()[:, :4])
    with pytest.raises(ValueError, match="needs stage2.diffusion.prediction=x0_readout"):
        from gspi.stage2.config import complete_stage2
        complete_stage2({"diffusion": {"readout_metal_gate": True}})


def test_an_x0_readout_model_learns_a_correction(lit):
    from gspi.stage2.data import scene_item
    from gspi.stage2.inputs import Stage2Inputs
    from gspi.stage2.loss import denoising_loss

    scene, _ = lit
    model = tiny_readout_model(LIGHT)
    xyz, cond, f0 = scene_item(scene, np.arange(0, scene.num_points, 5)[:256], LIGHT, np.random.default_rng(0))
    inputs = Stage2Inputs(xyz=torch.from_numpy(xyz)[None], local_cond=torch.from_numpy(cond)[None], global_tokens=None)
    loss = denoising_loss(model, torch.from_numpy(f0)[None], inputs, generator=torch.Generator().manual_seed(0))
    loss.backward()
    assert model.out.weight.grad.abs().sum() > 0  # the zero layer is trained


def test_x0_readout_needs_the_readout_condition():
    from gspi.stage2.config import complete_stage2
    from gspi.stage2.model import RCWConfig
    from gspi.stage2.train import rcw_config

    with pytest.raises(ValueError, match="needs stage2.data.light_readout=true"):
        rcw_config(complete_stage2({"diffusion": {"prediction": "x0_readout"}}), 0)
    cfg = rcw_config(complete_stage2({"diffusion": {"prediction": "x0_readout"},
                                      "data": {"light_readout": True, "cross_view_radiance": True}}), 0)
    assert cfg.readout_column == 35 + 5 and cfg.local_cond_dim == 35 + 5 + LIGHT_READOUT_WIDTH
    with pytest.raises(ValueError, match="go together"):
        RCWConfig(prediction="x0_readout")


def test_the_light_is_read_in_the_photos_where_they_were_taken_at_the_lattice(lit):
    """Issue 66, item 3: the scene's photos at the lattice cameras, the asset for geometry only."""
    import dataclasses

    from gspi.stage2.light_views import lattice_photos, views_to_read

    _, root = lit
    renders = gt_views_as_renders(root)
    photos, views = lattice_photos(root, renders)
    assert views == "photos" and photos.rgb.shape == renders.rgb.shape
    flat = dataclasses.replace(renders, rgb=np.full_like(renders.rgb, 0.3))  # an asset that lost every highlight
    images, depth = views_to_read(flat, photos)
    np.testing.assert_array_equal(images, renders.rgb)
    assert np.all(depth[~photos.mask] == 0) and np.array_equal(depth[photos.mask], renders.depth[photos.mask])
    np.testing.assert_array_equal(views_to_read(flat, None)[0], flat.rgb)
    moved = dataclasses.replace(renders, w2c=renders.w2c.copy())
    moved.w2c[3, 0, 3] += 0.01
    assert lattice_photos(root, moved) == (None, "renders (the photos were not taken at the lattice cameras)")
    assert lattice_photos(root.parent / "nowhere", renders)[0] is None


def test_the_condition_on_an_asset_is_read_as_a_run_reads_it(lit, tmp_path):
    """``stage2.data.light_geometry=asset`` (a reconstructed pool scene): the read-out on Stage I's
    cloud of the scene's Stage 0 asset (written beside it by ``gspi.stage1.pool_clouds``, which
    resumes), in the source scene's photos, each GT point taking its
    nearest row; with the light estimated (the measure), the rows equal those a run builds from
    the same asset (``inference_light_table``, ``method=light_fit``'s path), and a scene without
    an asset is told so in one line."""
    import dataclasses

    from eval.common.layout import read_scene
    from gspi.gaussians.ply import read_ply
    from gspi.recon.reconstructed_pool import reconstruct_pool
    from gspi.stage1.config import Stage1Config
    from gspi.stage1.pool_clouds import write_pool_stage1
    from gspi.stage1.extract import extract_point_cloud
    from gspi.stage2.light_condition import asset_views, photo_source, readout_lookup
    from gspi.stage2.light_fit import inference_light_table
    from gspi.stage2.light_views import lattice_photos

    _, root = lit
    (tmp_path / "src").mkdir()
    src = tmp_path / "src" / root.name
    src.symlink_to(root, target_is_directory=True)
    (tmp_path / "src" / "splits.json").write_text('{"train": ["lit_sphere"], "val": [], "test": []}')
    reconstruct_pool(tmp_path / "src", tmp_path / "rpool", recon="tiny",
                     overrides=("recon.iterations=60", "recon.init.num_points=400", "recon.densify.refine_stop_iter=0"))
    pooled = tmp_path / "rpool" / "lit_sphere"
    assert photo_source(pooled).resolve() == root.resolve() and photo_source(root) == root
    cfg = dataclasses.replace(LIGHT, light_geometry="asset", light_normal_search_deg=(4.0,), light_normal_profile=2)
    with pytest.raises(ValueError, match=r"asset/stage1/renders.npz: no Stage I .* gspi.stage1.pool_clouds"):
        asset_views(pooled)
    assert write_pool_stage1(tmp_path / "rpool") == 1 and write_pool_stage1(tmp_path / "rpool") == 0  # resumes
    seen = asset_views(pooled)
    assert seen.views == "photos"
    scene = load_scene_points(pooled, None)
    scene.light_source = "estimated"
    rows = scene.light_features(np.arange(scene.num_points), cfg)
    assert rows.shape == (scene.num_points, LIGHT_READOUT_WIDTH) and scene.light_info["env"] == ENV
    points, renders, _ = extract_point_cloud(read_ply(pooled / "asset" / "point_cloud.ply"),
                                             Stage1Config(image_size=read_scene(pooled).width))
    photos, _ = lattice_photos(root, renders)
    table, light = inference_light_table(points, renders, cfg, photos)
    assert light["env"] == ENV
    np.testing.assert_allclose(readout_lookup(table, scene.xyz), rows, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match=r"renders.npz: no Stage I of the scene's asset"):
        load_scene_points(root, None).light_features(np.arange(3), cfg)
    with pytest.raises(ValueError, match="light_geometry must be one of cloud, asset"):
        PointDataConfig.from_mapping({"light_geometry": "mesh"})
