"""The report shows the images that were scored (issue 25, item 1): under every shipped preset,
every image gspi-eval hands to its metrics equals, pixel for pixel, the panel the HTML report
shows for it and the run figure's image; error maps lie inside the scored mask."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from hydra import compose, initialize_config_dir

import eval.evaluate as evaluate_module
from eval.scoring import encode_albedo, metric_space
import eval.scoring as scoring_module
from eval.config import register_configs, validate_protocol
from eval.common.layout import read_scene
from eval.protocol_id import protocol_dict, scored_split
from eval.report_site.collect import Job
from eval.report_site.panels import scene_panels
from eval.report_site.run_figure import figure_panels
from eval.scored_view import EnvironmentCache, albedo_scales, apply_scales, scene_scored_views
from tests.fixtures import make_dataset, make_prediction

CONF = Path(__file__).resolve().parents[1] / "conf"
PRESETS = sorted(p.stem for p in (CONF / "eval").glob("*.yaml"))


def preset(name: str):
    register_configs()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="gspi_eval", overrides=[f"eval={name}", "gt=g", "pred=p", "out=o"])
    validate_protocol(cfg.eval)
    return cfg.eval


class FakeNet:
    """Stands in for LPIPS: the test compares images, not scores."""

    def __init__(self, name):
        self.net_name = name


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("scored")
    gt = make_dataset(root / "gt", num_scenes=1, size=48)
    return gt, root


def scored_inputs(gt: Path, pred: Path, protocol, monkeypatch) -> list[tuple[dict, torch.Tensor, torch.Tensor]]:
    """Runs gspi-eval's evaluate, recording what each row's metrics were given."""
    calls = []

    def recorder(images, mask, *args, **kwargs):
        p, g = images["psnr"]  # the pair PSNR reads (the report shows albedo in that space)
        calls.append((p.detach().clone(), g.detach().clone()))
        return {"psnr": 0.0, "psnr_floored": False, "ssim": 0.0, "lpips": 0.0}

    monkeypatch.setattr(scoring_module, "score_images", recorder)
    result = evaluate_module.evaluate(gt, pred, protocol, net=FakeNet(protocol.lpips.net))
    assert len(result.rows) == len(calls)
    return [(row, p, g) for row, (p, g) in zip(result.rows, calls)]


@pytest.mark.parametrize("name", PRESETS)
def test_report_panels_and_run_figure_are_the_scored_images(data, name, monkeypatch, tmp_path):
    gt, root = data
    protocol = preset(name)
    split = scored_split(protocol)
    pred = make_prediction(gt, tmp_path / "pred", albedo_scale=1.4, split=split)  # alignment matters
    scored = scored_inputs(gt, pred, protocol, monkeypatch)
    scene = read_scene(gt / "sphere_0")
    job = Job(run_dir=tmp_path, method="m", ablation="full", table="table1", seed=0, label="M", data=gt,
              predictions=pred, eval_dir=None, scenes=("sphere_0",), protocol=protocol_dict(protocol))
    panels, _ = scene_panels(scene, [job], {"M": pd.DataFrame()}, split=split)
    by_view = {vp.view: vp for vp in panels}
    views, _ = scene_scored_views(scene, pred / "sphere_0", protocol, EnvironmentCache())
    figures = {sv.view: {title: p for title, _, p, _ in figure_panels(sv, protocol)} for sv in views}
    checked = 0
    for row, p, g in scored:
        vp = by_view[row["view"]]
        key = row["channel"] if row["channel"] != "relight" else f"relit:{row['env']}"
        panel = vp.jobs["M"][key]
        shown = torch.from_numpy(panel.image).double()
        fig = torch.from_numpy(figures[row["view"]][key.replace("relit:", "relit: ")]).double()
        if row["channel"] == "albedo":  # the report shows albedo as stored; PSNR reads its space
            space = metric_space(protocol, "psnr")
            shown, fig = encode_albedo(shown, space), encode_albedo(fig, space)
        if row["channel"] in ("roughness", "metallic"):
            shown = shown[..., :1]
        torch.testing.assert_close(shown, p.double().cpu(), atol=1e-6, rtol=0)
        torch.testing.assert_close(fig, p.double().cpu(), atol=1e-6, rtol=0)
        if row["channel"] == "relight":
            torch.testing.assert_close(torch.from_numpy(vp.gt[key]).double(), g.double().cpu(), atol=1e-6, rtol=0)
        mask = next(sv.mask for sv in views if sv.view == row["view"]).numpy()
        assert not panel.error[~mask].any()               # error maps inside the scored mask only
        checked += 1
    assert checked == len(scored) > 0


def align_albedo(pred, gt, masks, mode, scope):
    """The aligned albedos as scene_scored_views computes them (scales, then applied)."""
    return apply_scales(pred, albedo_scales(pred, gt, masks, mode, scope), masks)


def test_align_albedo_scene_scope_pools_views_and_view_scope_does_not():
    gt = [torch.full((4, 4, 3), 0.5, dtype=torch.float64) for _ in range(2)]
    pred = [torch.full((4, 4, 3), 0.25, dtype=torch.float64), torch.full((4, 4, 3), 0.5, dtype=torch.float64)]
    masks = [torch.ones(4, 4, dtype=torch.bool)] * 2
    per_view = align_albedo(pred, gt, masks, "scale", "view")
    for a, g in zip(per_view, gt):
        torch.testing.assert_close(a, g)                    # each view fitted alone: exact
    pooled = align_albedo(pred, gt, masks, "scale", "scene")
    assert not torch.allclose(pooled[0], gt[0]) and not torch.allclose(pooled[1], gt[1])
    with pytest.raises(ValueError, match="alignment_scope"):
        align_albedo(pred, gt, masks, "scale", "frame")


def test_erosion_shrinks_the_scored_mask(data, tmp_path):
    gt, _ = data
    pred = make_prediction(gt, tmp_path / "pred")
    scene = read_scene(gt / "sphere_0")
    plain, _ = scene_scored_views(scene, pred / "sphere_0", preset("default"), EnvironmentCache())
    eroded, _ = scene_scored_views(scene, pred / "sphere_0", preset("stanford_orb"), EnvironmentCache())
    for a, b in zip(plain, eroded):
        assert b.mask.sum() < a.mask.sum() and not (b.mask & ~a.mask).any()
        assert np.isfinite(b.pred["albedo"].numpy()).all()


def test_relight_clamp_albedo_false_shades_the_unclamped_aligned_albedo(data):
    """relight.clamp_albedo: false (TensoIR relights albedo * ratio as it is): the relit
    prediction is shaded with the aligned albedo continued past 1, not the clamped one."""
    from eval.common.colorspace import srgb_to_linear
    from eval.protocol import apply_albedo_scale, unclamped_linear_albedo
    from eval.scored_view import load_gt_view, relit_pairs
    from eval.views import relight_view

    gt_root, _ = data
    scene = read_scene(gt_root / "sphere_0")
    view = scene.split_views("test")[0]
    envs = EnvironmentCache()
    g = load_gt_view(scene, view)
    raw = torch.full_like(g["albedo"], 0.9)
    scale = torch.tensor([2.0, 1.5, 0.5], dtype=torch.float64)
    clamped, free = preset("tensoir"), preset("tensoir")
    clamped.relight.clamp_albedo = True
    space = free.alignment_space  # linear: TensoIR's albedo.png values are linear (version 3)
    p = {"albedo": apply_albedo_scale(raw, scale, space), "roughness": g["roughness"], "metallic": g["metallic"]}
    kept = relit_pairs(scene, g, p, raw, scale, g["mask"], clamped, envs)
    unkept = relit_pairs(scene, g, p, raw, scale, g["mask"], free, envs)
    lin = unclamped_linear_albedo(raw, scale, space)
    torch.testing.assert_close(lin[0, 0], srgb_to_linear(torch.tensor([0.9] * 3, dtype=torch.float64)) * scale)
    assert lin[..., 0].max() > 1.0 and lin[..., 2].max() < 1.0  # only the channels that clip differ
    env = next(iter(unkept))
    want = relight_view(None, g["roughness"], g["metallic"], g["normal"], g["view_dir"],
                        envs.get(scene.envmap_path(env)), albedo_linear=lin.to(raw.dtype))
    assert not torch.allclose(kept[env].pred_linear, unkept[env].pred_linear)
    torch.testing.assert_close(unkept[env].pred_linear, want)


def test_environment_cache_prefilters_each_distinct_map_once(tmp_path, monkeypatch):
    """Files with the same pixels (each scene's copy of a shared map) share one prefiltering."""
    import eval.relight as relight
    from eval.common.imageio import write_exr

    calls = []
    real = relight.prefilter_environment
    monkeypatch.setattr(relight, "prefilter_environment", lambda env: calls.append(1) or real(env))
    g = np.random.default_rng(0)
    sky, other = g.random((8, 16, 3), dtype=np.float32), g.random((8, 16, 3), dtype=np.float32)
    for name, image in (("a", sky), ("b", sky), ("c", other)):
        write_exr(tmp_path / f"{name}.exr", image)
    cache = EnvironmentCache()
    a, b, c = (cache.get(tmp_path / f"{n}.exr") for n in "abc")
    assert a is b and a is not c and len(calls) == 2
    assert cache.get(tmp_path / "a.exr") is a and len(calls) == 2
