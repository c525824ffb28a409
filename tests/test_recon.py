"""Stage 0 (gspi-recon): reconstruction of a tiny generated scene, densification, lattice renders."""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from gspi.data.lattice import lattice_cameras
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.ply import read_ply, write_ply
from gspi.gaussians.rasterize import rasterize_2dgs
from gspi.gaussians.lattice_render import render_lattice_views
from gspi.recon import ReconInputError, load_scene_views
from gspi.recon.init import in_hull, init_gaussians
from gspi.recon.render import render_views
from tests.recon_fixtures import STRATEGY_CFG, densify_case, densify_step, random_surfels
from gspi.recon.strategy import (BuiltinDefaultStrategy, from_params, gsplat_strategy_available, make_strategy,
                                 maybe_reset_opacity)

REPO = Path(__file__).resolve().parents[1]
SIZE = 48


@pytest.fixture(autouse=True, scope="module")
def _single_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    """One generated scene (torus, rough plastic) at 48 px with 2 held-out views (~4 s)."""
    from eval.common.argv import apply_aliases
    from gspi.cli.data import run as data_run

    out = tmp_path_factory.mktemp("recon_data")
    overrides = ["preset=tiny", f"out={out}", "seed=0", "data.num_train_scenes=1", "data.num_val_scenes=0",
                 "data.num_test_scenes=0", f"data.image_size={SIZE}", "data.env_height=16",
                 "data.num_test_views=2", "data.num_val_views=0", "data.num_relight_envs=1",
                 "data.contact_sheets=false", "data.point_clouds=false"]
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        data_run(compose("gspi_data", overrides=apply_aliases(overrides, "gspi_data")))
    (scene,) = [p for p in out.iterdir() if (p / "scene.json").is_file()]
    return scene


def recon_config(scene: Path, out: Path, extra: list[str] | None = None):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base="1.3"):
        return compose("gspi_recon", overrides=[f"scene={scene}", f"out={out}", "recon=tiny", *(extra or [])])


@pytest.fixture(scope="module")
def recon_run(scene_dir, tmp_path_factory):
    from gspi.cli.recon import run

    out = tmp_path_factory.mktemp("recon_out")
    return out, run(recon_config(scene_dir, out))


# ---- end to end ----------------------------------------------------------------------------------
def test_tiny_recon_improves_held_out_psnr(recon_run):
    _, summary = recon_run
    test, before = summary["test"], summary["test_initial"]
    assert test["num_views"] == 2
    assert test["psnr_masked"] > before["psnr_masked"] + 5.0, (before, test)
    assert test["psnr_masked"] > 21.0 and test["psnr_full"] > test["psnr_masked"]  # black background is easy
    assert 0.0 < test["ssim_masked"] <= 1.0 and test["alpha_iou"] > 0.8
    assert summary["train"]["psnr_masked"] > 22.0


def test_recon_json_fields(recon_run):
    out, summary = recon_run
    on_disk = json.loads((out / "recon.json").read_text())
    assert on_disk == json.loads(json.dumps(summary))
    for key in ("scene", "ply", "num_gaussians", "iterations", "wall_seconds", "seconds", "display_transform",
                "loss", "test", "test_initial", "train", "strategy", "sh_degree", "config", "history"):
        assert key in on_disk, key
    assert on_disk["iterations"] == 200 and on_disk["sh_degree"] == 3
    assert on_disk["image_size"] == [SIZE, SIZE] and on_disk["num_input_views"] == 32
    assert on_disk["wall_seconds"] > on_disk["seconds"]["train"] > 0
    for key in ("psnr_masked", "psnr_full", "ssim_masked", "ssim_full"):
        assert math.isfinite(on_disk["test"][key])
    assert len(on_disk["test"]["per_view"]) == 2
    assert "aces" in on_disk["display_transform"]


def test_gspi_run_cache_is_the_same_reconstruction_and_record(recon_run, scene_dir, tmp_path):
    """gspi-run's Stage 0 (assets=null) and gspi-recon are one path: same asset, same record."""
    from omegaconf import OmegaConf

    from eval.common.layout import read_scene
    from gspi.recon.reconstruct import reconstruction_seconds
    from gspi.run.assets import cached_reconstruction

    out, summary = recon_run
    cfg = OmegaConf.to_container(recon_config(scene_dir, out).recon, resolve=True)
    asset, info = cached_reconstruction(read_scene(scene_dir), cfg, tmp_path)
    cli_asset = read_ply(out / "point_cloud.ply")
    assert asset.num_gaussians == cli_asset.num_gaussians
    torch.testing.assert_close(asset.means, cli_asset.means)
    on_disk = json.loads((Path(info["path"]).parent / "recon.json").read_text())
    assert set(summary) - set(on_disk) == {"ply", "wall_seconds"}  # what only gspi-recon knows
    assert on_disk["format"] == summary["format"] == "gspi-recon/2" and on_disk["config"] == summary["config"]
    assert on_disk["test"]["psnr_masked"] == pytest.approx(summary["test"]["psnr_masked"], abs=1e-4)
    assert reconstruction_seconds(on_disk) == on_disk["seconds"]["total"] > 0
    assert reconstruction_seconds({"seconds": 12.5}) == 12.5  # the first schema's float, in old caches
    assert cached_reconstruction(read_scene(scene_dir), cfg, tmp_path)[1]["cached"]


def test_written_ply_is_the_official_layout_and_loads_back(recon_run):
    out, summary = recon_run
    g = read_ply(out / "point_cloud.ply")
    assert g.num_gaussians == summary["num_gaussians"] and g.sh_degree == 3 and not g.has_pbr
    assert torch.isfinite(g.means).all() and g.log_scales.shape[1] == 2
    from plyfile import PlyData
    names = [p.name for p in PlyData.read(str(out / "point_cloud.ply"))["vertex"].properties]
    assert len(names) == 61 and names[:6] == ["x", "y", "z", "nx", "ny", "nz"] and names[-4:] == [
        "rot_0", "rot_1", "rot_2", "rot_3"]


def test_fit_result_round_trips_through_ply(scene_dir, tmp_path):
    from gspi.recon.trainer import ReconConfig, fit_gaussians

    views = load_scene_views(scene_dir)
    cfg = ReconConfig.from_dict({"iterations": 20, "sh_degree": 2, "init": {"num_points": 300},
                                 "densify": {"refine_start_iter": 5, "refine_every": 10, "refine_stop_iter": 15}})
    result = fit_gaussians(views, cfg)
    write_ply(tmp_path / "p.ply", result.gaussians)
    back = read_ply(tmp_path / "p.ply")
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest"):
        assert torch.equal(getattr(back, name), getattr(result.gaussians, name)), name


def test_unknown_config_key_is_rejected():
    from gspi.recon.trainer import ReconConfig

    with pytest.raises(ValueError, match="lambda_ssim"):
        ReconConfig.from_dict({"loss": {"lambda_ssim": 0.2}})


# ---- input errors ----------------------------------------------------------------------------------
def test_missing_input_file_is_named(scene_dir, tmp_path):
    from gspi.cli.recon import run

    broken = tmp_path / "broken"
    shutil.copytree(scene_dir, broken)
    (broken / "train" / "005" / "mask.png").unlink()
    with pytest.raises(ReconInputError, match=r"train/005/mask\.png"):
        run(recon_config(broken, tmp_path / "out"))
    (broken / "scene.json").unlink()
    with pytest.raises(ReconInputError, match=r"scene\.json"):
        run(recon_config(broken, tmp_path / "out"))


# ---- initialisation --------------------------------------------------------------------------------
def test_init_points_lie_on_the_visual_hull(scene_dir):
    views = load_scene_views(scene_dir)
    g = init_gaussians(views, 500, 3, generator=torch.Generator().manual_seed(0))
    assert 400 <= g.num_gaussians <= 500 and g.sh_rest.shape == (g.num_gaussians, 15, 3)
    assert in_hull(g.means, views).all()
    # a small step towards the source camera leaves the hull for most points (they sit on its surface)
    cam = torch.linalg.inv(views.viewmats)[:, :3, 3]
    nearest = (g.means[:, None] - cam[None]).norm(dim=-1).argmin(1)
    step = torch.nn.functional.normalize(cam[nearest] - g.means, dim=-1) * 0.05
    assert (~in_hull(g.means + step, views)).float().mean() > 0.5


def test_views_with_an_empty_mask_do_not_carve_the_hull(scene_dir):
    """A single-sided asset seen from behind leaves empty masks (glTF culling); carving with them
    would empty the hull (ValueError 'visual hull is empty'), so only views with foreground carve."""
    from gspi.recon.init import visual_hull_points

    views = load_scene_views(scene_dir)
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    want, _, _ = visual_hull_points(views, 300, generator=gen())
    views.masks[: views.num_views // 2] = False   # half the views see nothing
    got, _, _ = visual_hull_points(views, 300, generator=gen())
    assert len(got) > 100
    carving = views.select(views.masks.reshape(views.num_views, -1).any(1))
    assert carving.num_views == views.num_views - views.num_views // 2 and in_hull(got, carving).all()
    assert not in_hull(got, views).any()  # with every view carving, none of them would be inside
    assert len(want) > 0


def test_facing_quats_put_the_normal_in_rotation_column_2():
    from gspi.gaussians.projection import quat_to_rotmat
    from gspi.recon.init import facing_quats

    n = torch.nn.functional.normalize(torch.randn(500, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    n = torch.cat([n, torch.eye(3), -torch.eye(3)])
    rot = quat_to_rotmat(facing_quats(n))
    assert torch.allclose(rot[..., 2], n, atol=1e-5)
    assert torch.allclose(rot.transpose(1, 2) @ rot, torch.eye(3).expand(len(n), 3, 3), atol=1e-5)


# ---- rendering with the densification gradient -----------------------------------------------------

def test_render_views_matches_rasterize_and_gives_gsplat_densify_gradient():
    g = random_surfels(40, dtype=torch.float64)
    g.log_scales = g.log_scales + 1.0  # ~3 px: the low-pass filter (ignored by gsplat's gradient) is inactive
    g.sh_rest = torch.zeros_like(g.sh_rest)  # no view-dependent colour: moving a centre = translating its splat
    viewmats, Ks = (torch.as_tensor(a, dtype=torch.float64) for a in lattice_cameras(width=32, height=32)[::-1])
    vm, K = viewmats[3:4], Ks[3:4]
    ref = rasterize_2dgs(g.means, g.quats, g.scales, g.opacities, g.sh, vm, K, 32, 32, sh_degree=3, backend="torch")
    weights = torch.rand(1, 32, 32, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)

    def loss_of(means):
        out = render_views(means, g.quats, g.scales, g.opacities, g.sh, 3, vm, K, 32, 32, densify_grad=True)
        return (out.rgb * weights).sum(), out

    loss, out = loss_of(g.means)
    assert torch.allclose(out.rgb, ref.rgb) and torch.allclose(out.alpha, ref.alpha)
    assert torch.allclose(out.depth_median, ref.depth_median)
    assert set(out.meta) >= {"gradient_2dgs", "radii", "width", "height", "n_cameras", "gaussian_ids"}
    loss.backward()
    grad = out.meta["gradient_2dgs"].grad[0]  # [N, 2]
    # = dL/d(pixel translation): finite difference of moving the centre along camera x / y at fixed depth
    i = int(grad.norm(dim=-1).argmax())
    z = float(out.meta["depths"][0, i])
    rot = vm[0, :3, :3]
    for axis in (0, 1):
        eps = 1e-4  # pixels
        shift = rot[axis] * eps * z / K[0, axis, axis]
        hi, _ = loss_of(g.means + torch.nn.functional.one_hot(torch.tensor(i), 40)[:, None] * shift)
        lo, _ = loss_of(g.means - torch.nn.functional.one_hot(torch.tensor(i), 40)[:, None] * shift)
        fd = float((hi - lo).detach()) / (2 * eps)
        assert abs(fd - float(grad[i, axis])) < 1e-3 * float(grad[i].norm()), (axis, fd, grad[i])


# ---- densify / prune --------------------------------------------------------------------------------




@pytest.mark.parametrize("impl", ["builtin", "gsplat"])
def test_densify_and_prune_counts(impl):
    if impl == "gsplat" and not gsplat_strategy_available():
        pytest.skip("gsplat not installed")
    strategy, name = make_strategy(STRATEGY_CFG, impl)
    assert impl in name.lower()
    params, optimizers, info = densify_case()
    before = from_params(params)
    state = strategy.initialize_state(scene_scale=1.0)
    strategy.step_pre_backward(params, optimizers, state, 200, info)
    torch.manual_seed(0)
    strategy.step_post_backward(params, optimizers, state, 200, info, packed=False)
    # 10 + 2 duplicated (0, 1) + 2 split (4, 5 -> 4 children) - 2 pruned (2, 6) = 12
    after = from_params(params)
    assert after.num_gaussians == 12
    for k, p in params.items():
        st = optimizers[k].state[p]
        assert st["exp_avg"].shape == p.shape and optimizers[k].param_groups[0]["params"][0] is p
    # split children (appended last): scales / 1.6, centres displaced in the surfel plane only
    children = after.means[-4:]
    parents = before.means[[4, 5, 4, 5]]
    assert torch.allclose(after.log_scales[-4:], before.log_scales[[4, 5, 4, 5]] - math.log(1.6))
    normals = before.normals[[4, 5, 4, 5]]
    assert ((children - parents) * normals).sum(-1).abs().max() < 1e-6
    assert (children - parents).norm(dim=-1).min() > 0
    # no pruning by size before the first reset interval; after it, large ones (scale > 0.1) go
    assert (after.scales.max(-1).values > 0.1).sum() == 3  # 7, 8, 9 still there
    strategy.step_post_backward(params, optimizers, state, 600, info_like(info, len(params["means"])), packed=False)
    assert (from_params(params).scales.max(-1).values > 0.1).sum() == 0


def info_like(info: dict, n: int) -> dict:
    densify = torch.zeros(1, n, 2, requires_grad=True)
    densify.grad = torch.zeros(1, n, 2)
    return {**info, "gradient_2dgs": densify, "radii": torch.ones(1, n, 2, dtype=torch.int32)}


def test_builtin_strategy_matches_gsplat():
    if not gsplat_strategy_available():
        pytest.skip("gsplat not installed (the recorded golden below runs everywhere)")
    (pa, oa), (pb, ob) = densify_step("builtin"), densify_step("gsplat")
    for k in pa:
        assert torch.allclose(pa[k], pb[k], atol=1e-6), (k, (pa[k] - pb[k]).abs().max())
        assert torch.equal(oa[k].state[pa[k]]["exp_avg_sq"], ob[k].state[pb[k]]["exp_avg_sq"]), k


def test_builtin_strategy_matches_the_recorded_gsplat_golden():
    """gsplat's DefaultStrategy result, recorded once (tests/golden/record_oracles.py), equals the port."""
    golden = json.loads((REPO / "tests" / "golden" / "gsplat_densify.json").read_text())
    assert golden["producer"]["gsplat"] == "1.5.3"
    params, optimizers = densify_step("builtin")
    assert set(params) == set(golden["params"])
    for k, p in params.items():
        want = torch.tensor(golden["params"][k], dtype=p.dtype)
        assert p.shape == want.shape, k
        torch.testing.assert_close(p.detach(), want, atol=1e-6, rtol=0, msg=k)
        torch.testing.assert_close(optimizers[k].state[p]["exp_avg_sq"],
                                   torch.tensor(golden["exp_avg_sq"][k], dtype=p.dtype), atol=1e-12, rtol=1e-6,
                                   msg=k)


def test_opacity_reset():
    strategy = BuiltinDefaultStrategy(**STRATEGY_CFG)
    params, optimizers, _ = densify_case()
    assert not maybe_reset_opacity(strategy, params, optimizers, {}, 499)
    assert maybe_reset_opacity(strategy, params, optimizers, {}, 500)
    assert torch.sigmoid(params["opacities"]).max() <= 0.01 + 1e-6
    assert optimizers["opacities"].state[params["opacities"]]["exp_avg"].abs().max() == 0
    assert not maybe_reset_opacity(strategy, params, optimizers, {}, 1000)  # outside the refine window


# ---- lattice renders ----------------------------------------------------------------------------
def test_render_lattice_views_shapes_and_cameras(scene_dir):
    g = random_surfels(60)
    out = render_lattice_views(g, image_size=24)
    assert out.rgb.shape == (32, 24, 24, 3) and out.alpha.shape == (32, 24, 24, 1)
    assert out.depth_median.shape == (32, 24, 24, 1) and out.normals.shape == (32, 24, 24, 3)
    K, w2c = lattice_cameras(width=24, height=24)
    assert np.allclose(out.meta["viewmats"].numpy(), w2c, atol=1e-6)
    assert np.allclose(out.meta["Ks"].numpy(), K, atol=1e-5)
    assert out.alpha.amax(dim=(1, 2, 3)).min() > 0  # every view sees the asset
    # camera binding: one opaque surfel off-centre lands at its projection in each view k
    # (three orthogonal surfels at one point, so that no view sees only an edge)
    one = Gaussians2D.empty(3, 0)
    one.means = torch.tensor([[0.3, -0.2, 0.25]]).repeat(3, 1)
    h = math.sqrt(0.5)
    one.quats = torch.tensor([[1.0, 0.0, 0.0, 0.0], [h, 0.0, h, 0.0], [h, h, 0.0, 0.0]])
    one.log_scales = torch.full((3, 2), math.log(0.03))
    one.opacity_logits = torch.full((3,), 4.0)
    out1 = render_lattice_views(one, image_size=(40, 48))
    assert out1.alpha.shape == (32, 40, 48, 1)
    K, w2c = lattice_cameras(width=48, height=40)
    for k in (0, 7, 31):
        p = K[k] @ (w2c[k, :3, :3] @ one.means[0].double().numpy() + w2c[k, :3, 3])
        a = out1.alpha[k, ..., 0].double()
        rows, cols = torch.meshgrid(torch.arange(40) + 0.5, torch.arange(48) + 0.5, indexing="ij")
        centroid = np.array([float((a * cols).sum() / a.sum()), float((a * rows).sum() / a.sum())])
        assert np.abs(centroid - p[:2] / p[2]).max() < 0.75, (k, centroid, p[:2] / p[2])
    # the generated scene's train cameras are the lattice cameras
    views = load_scene_views(scene_dir)
    vm, Ks = out.meta["viewmats"], out.meta["Ks"] * (SIZE / 24.0)
    Ks[:, 2, 2] = 1.0
    assert torch.allclose(views.viewmats, vm, atol=1e-5) and torch.allclose(views.Ks, Ks, atol=1e-4)


def test_held_out_views_that_show_nothing_are_listed_not_scored(scene_dir, tmp_path):
    """A held-out view whose mask is empty (a single-sided card seen from behind: several of the
    real objects' views) is listed in the record's empty_views and left out of the means; with
    no view left the means are None. Before, Stage 0's held-out evaluation raised "mask is
    empty" and the whole scene failed in gspi-run."""
    import imageio.v3 as iio

    from gspi.cli.recon import run

    scene = tmp_path / "scene"
    shutil.copytree(scene_dir, scene)
    test_dirs = sorted(p for p in (scene / "test").iterdir() if p.is_dir())
    for i, view in enumerate(test_dirs):
        mask = iio.imread(view / "mask.png")
        iio.imwrite(view / "mask.png", np.zeros_like(mask))
        one = run(recon_config(scene, tmp_path / f"out{i}", ["recon.iterations=10"]))["test"]
        blanked = [p.name for p in test_dirs[:i + 1]]
        assert one["empty_views"] == blanked and one["num_views"] == len(test_dirs) - i - 1
        assert [v["view"] for v in one["per_view"]] == [p.name for p in test_dirs[i + 1:]]
    assert one["psnr_masked"] is None and one["alpha_iou"] is None
