"""Tests of Stage II training, checkpoints, inference and the gspi-train config (tiny sizes, 1 thread)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from eval.common.conf import CONF_DIR
from eval.common.argv import apply_aliases
from gspi.cli.train import run
from gspi.stage2.checkpoint import CheckpointError, export_ema_only, load_stage2_checkpoint
from gspi.stage2.config import complete_stage2
from gspi.stage2.sampler import predict_point_pbr
from gspi.stage2.train import LOSS_KEY, TrainState, rcw_config, train
from gspi.stage2.train_log import JsonlMetrics
from tests.stage2_fixtures import compose_cfg, lattice_dataset, tiny_cfg  # noqa: F401  (fixture `dataset`)

ABLATIONS = ("full", "a1_no_global_prior", "a2_no_view_onehot", "a3_npts_1024", "a4_npts_1024_nlat_384",
             "a5_multiview_injection")


@pytest.mark.parametrize("ablation", ABLATIONS)
def test_ablation_configs_change_one_thing(ablation):
    cfg = OmegaConf.to_container(compose_cfg(["data_dir=d", "out=o", f"ablation={ablation}"]), resolve=True)
    full = OmegaConf.to_container(compose_cfg(["data_dir=d", "out=o"]), resolve=True)
    s2, ref = cfg["stage2"], full["stage2"]
    dim = {"none": 0, "alexnet": 256}[s2["prior"]["encoder"]]
    model = rcw_config(s2, dim)
    expected = {
        "full": ("alexnet", "top_rgb_onehot", 512, 256, 35),
        "a1_no_global_prior": ("none", "top_rgb_onehot", 512, 256, 35),
        "a2_no_view_onehot": ("alexnet", "top_rgb", 512, 256, 3),
        "a3_npts_1024": ("alexnet", "top_rgb_onehot", 1024, 256, 35),
        "a4_npts_1024_nlat_384": ("alexnet", "top_rgb_onehot", 1024, 384, 35),
        "a5_multiview_injection": ("alexnet", "multiview", 512, 256, 128),
    }[ablation]
    got = (s2["prior"]["encoder"], s2["data"]["local_condition"], s2["data"]["num_points"],
           s2["model"]["num_latents"], model.local_cond_dim)
    assert got == expected
    assert model.use_view_onehot == (expected[1] == "top_rgb_onehot")
    assert model.global_token_dim == dim
    for key in ("diffusion", "train", "eval"):
        assert s2[key] == ref[key]
    text = (Path(CONF_DIR) / "ablation" / f"{ablation}.yaml").read_text()
    # Hydra reads the package header only before the first other line: it comes first, the paper row next
    assert text.splitlines()[0] == "# @package _global_" and text.splitlines()[1].startswith("# Table 2 ")


def test_stage2_presets_compose():
    import yaml

    for preset in ("default", "tiny", "cpu_pool224_pixel_5k"):  # the paper, the smoke size, gspi-run's
        cfg = compose_cfg(["data_dir=d", "out=o", f"stage2={preset}"])
        own = yaml.safe_load((Path(CONF_DIR) / "stage2" / f"{preset}.yaml").read_text())
        # the preset's own values win over what it inherits (content, not just presence)
        for section in ("data", "train"):
            for key, value in (own.get(section) or {}).items():
                assert cfg.stage2[section][key] == value, (preset, section, key)
        assert cfg.stage2.prior.encoder == "alexnet"
    assert compose_cfg(["data_dir=d", "out=o", "stage2=tiny"]).stage2.data.num_points != \
        compose_cfg(["data_dir=d", "out=o", "stage2=default"]).stage2.data.num_points
    assert apply_aliases(["data=/x", "out=o", "stage2.data.num_points=3"], "gspi_train") == \
        ["data_dir=/x", "out=o", "stage2.data.num_points=3"]


def test_training_loss_decreases(dataset, tmp_path):
    cfg = tiny_cfg(dataset, tmp_path, "stage2.train.steps=80", "stage2.train.checkpoint_every=1000",
                   "stage2.train.batch_size=4", "stage2.train.warmup_steps=5", "stage2.prior.encoder=none")
    stats = train(cfg, tmp_path)
    _, losses = JsonlMetrics(tmp_path / "metrics.jsonl").series(LOSS_KEY)
    assert len(losses) == 80 and stats["steps"] == 80
    assert losses[-20:].mean() < 0.6 * losses[:10].mean()
    assert (tmp_path / "loss_curve.png").is_file()


def test_resume_continues_exactly(dataset, tmp_path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    cfg_a = tiny_cfg(dataset, straight)
    cfg_b = tiny_cfg(dataset, resumed)
    train(cfg_a, straight)
    train(cfg_b, resumed, stop_at=5)  # "interrupted" after 5 of 10 steps
    first = torch.load(resumed / "checkpoint.pt", weights_only=True)
    assert first["step"] == 5
    stats = train(cfg_b, resumed)
    assert stats["resumed_from"] == 5 and stats["steps"] == 10
    a = torch.load(straight / "checkpoint.pt", weights_only=True)
    b = torch.load(resumed / "checkpoint.pt", weights_only=True)
    for key in ("model", "ema"):
        for name, value in a[key].items():
            assert torch.equal(value, b[key][name]), f"{key}.{name} differs after resume"
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values()):
        assert torch.equal(sa["exp_avg"], sb["exp_avg"]) and torch.equal(sa["exp_avg_sq"], sb["exp_avg_sq"])
    assert a["rng"]["numpy"] == b["rng"]["numpy"]
    assert (straight / "metrics.jsonl").read_text() == (resumed / "metrics.jsonl").read_text()


def test_checkpoint_roundtrip_and_ema_export(dataset, tmp_path):
    cfg = tiny_cfg(dataset, tmp_path, "stage2.train.steps=3")
    train(cfg, tmp_path)
    model, saved = load_stage2_checkpoint(tmp_path / "checkpoint.pt")
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    for name, value in model.state_dict().items():
        assert torch.equal(value, ckpt["ema"][name])  # the EMA weights, not the raw ones
    assert not model.training and saved["stage2"].model == complete_stage2(cfg["stage2"]).model and saved["seed"] == 0
    for half in (False, True):
        dst = export_ema_only(tmp_path / "checkpoint.pt", tmp_path / f"ema_{half}.pt", half=half)
        shipped = torch.load(dst, weights_only=True)
        assert "optimizer" not in shipped and "model" not in shipped
        model2, _ = load_stage2_checkpoint(dst)
        for name, value in model.state_dict().items():
            torch.testing.assert_close(model2.state_dict()[name], value, atol=1e-3 if half else 0, rtol=1e-3 if half else 0)


def test_bad_checkpoints_name_the_file(dataset, tmp_path):
    missing = tmp_path / "nothing.pt"
    with pytest.raises(FileNotFoundError, match="nothing.pt"):
        load_stage2_checkpoint(missing)
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(CheckpointError, match="corrupt.pt"):
        load_stage2_checkpoint(corrupt)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}}, foreign)
    with pytest.raises(CheckpointError, match="foreign.pt.*not a Stage II checkpoint"):
        load_stage2_checkpoint(foreign)
    cfg = tiny_cfg(dataset, tmp_path, "stage2.train.steps=1")
    train(cfg, tmp_path)
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    ckpt["rcw_config"]["point_dim"] = 32  # weights no longer fit
    torch.save(ckpt, tmp_path / "mismatch.pt")
    with pytest.raises(CheckpointError, match="mismatch.pt.*do not fit"):
        load_stage2_checkpoint(tmp_path / "mismatch.pt")
    other = tiny_cfg(dataset, tmp_path, "stage2.train.steps=2", "stage2.model.point_dim=32")
    with pytest.raises(CheckpointError, match="checkpoint.pt.*differs"):
        train(other, tmp_path)  # resuming into a different model is refused


def test_prediction_range_and_determinism(dataset):
    cfg = tiny_cfg(dataset, Path("unused"))
    torch.manual_seed(0)
    cfg = {**cfg, "stage2": complete_stage2(cfg["stage2"])}  # TrainState takes the checked config
    state = TrainState(cfg, rcw_config(cfg["stage2"], 256))
    model = state.ema
    g = torch.Generator().manual_seed(0)
    xyz = torch.randn(300, 3, generator=g)
    cond = torch.rand(300, 35, generator=g)
    feats = torch.randn(32, 256, 5, 5, generator=g)
    a = predict_point_pbr(model, xyz, cond, feats, num_steps=3, seed=1, write_chunk=64)
    b = predict_point_pbr(model, xyz, cond, feats, num_steps=3, seed=1, write_chunk=None)
    c = predict_point_pbr(model, xyz, cond, feats, num_steps=3, seed=2)
    assert a.shape == (300, 5) and a.min() >= 0 and a.max() <= 1
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)  # chunking changes nothing but rounding
    assert torch.equal(a, predict_point_pbr(model, xyz, cond, feats, num_steps=3, seed=1, write_chunk=64))
    assert not torch.equal(a, c)


def test_run_smoke_writes_run_files(dataset, tmp_path):
    cfg = compose_cfg([f"data_dir={dataset}", f"out={tmp_path}", "stage2=tiny", "stage2.train.steps=4",
                       "stage2.prior.alexnet.input_size=64", "stage2.eval.enabled=true", "stage2.eval.num_steps=2",
                       "ablation=a5_multiview_injection"])
    stats = run(cfg)
    for name in ("checkpoint.pt", "metrics.jsonl", "loss_curve.png", "stats.json", "eval_points/table.md",
                 "eval_points/scores.json"):
        assert (tmp_path / name).is_file(), name
    assert json.loads((tmp_path / "stats.json").read_text())["steps"] == 4
    scores = json.loads((tmp_path / "eval_points" / "scores.json").read_text())
    assert set(scores["mean"]) == {"stage2", "no_decomposition"}
    for method in scores["mean"].values():
        assert set(method) == {"albedo", "roughness", "metallic", "avg"}
        assert all(np.isfinite(v) for ch in method.values() for v in ch.values())
    assert "No decomposition" in (tmp_path / "eval_points" / "table.md").read_text()
    assert stats["eval_points"]["split"] == "test"
    # the folder is a Table 2 run of its ablation for gspi-table (eval/records/points_scores.py)
    assert (scores["format"], scores["ablation"], scores["checkpoint_step"]) == \
        ("gspi-points-eval", "a5_multiview_injection", 4)
    from eval.tables.cli import load_sources
    from eval.tables.build import TABLE_SPECS, build_sweep_table
    table = build_sweep_table(load_sources([tmp_path / "eval_points"], ("table2",)), TABLE_SPECS["table2"])
    assert table.labels == ["No decomposition", "A5: Direct multi-view injection"]
    assert table.mean.loc["A5: Direct multi-view injection", "psnr/avg"] == \
        pytest.approx(scores["mean"]["stage2"]["avg"]["psnr"])


def test_cpu_time_budget_counts_process_cpu_not_wall_time(monkeypatch):
    """stop_after_cpu_minutes: a budget that a busy machine does not shrink (wall time passes,
    CPU time does not)."""
    import gspi.stage2.train as train_module

    clock = {"wall": 0.0, "cpu": 0.0}
    monkeypatch.setattr(train_module.time, "perf_counter", lambda: clock["wall"])
    monkeypatch.setattr(train_module.time, "process_time", lambda: clock["cpu"])
    budget = train_module.Budget(None, 1.0)
    clock["wall"] = 3600.0           # an hour of waiting for the cores
    assert not budget.spent()
    clock["cpu"] = 60.0               # one minute of this process's CPU time
    assert budget.spent()
    wall = train_module.Budget(2.0, None)
    clock["wall"] += 119.0
    assert not wall.spent()
    clock["wall"] += 1.0
    assert wall.spent()


def test_a_spent_cpu_budget_stops_before_the_first_step(dataset, tmp_path):
    stats = train(tiny_cfg(dataset, tmp_path), tmp_path, stop_after_cpu_minutes=0.0)
    assert stats["steps"] == 0 and (tmp_path / "checkpoint.pt").is_file()


def test_checkpoint_clock_and_run_log(dataset, tmp_path, monkeypatch):
    """stage2.train.checkpoint_minutes saves between the step-based checkpoints (0: every step),
    a run resumed from such a checkpoint equals an uninterrupted one, and every finished run
    appends one line to stage2.train.run_log, naming the commit the run started from."""
    import gspi.stage2.train as train_mod

    saved_steps, saves = [], {"n": 0}
    real_save = train_mod.save_checkpoint

    def counting_save(state, cfg, out_dir):
        saved_steps.append(state.step)
        saves["n"] += 1
        return real_save(state, cfg, out_dir)

    monkeypatch.setattr(train_mod, "save_checkpoint", counting_save)
    # a checkout that moves on while a run trains: the "commit" changes with every checkpoint
    monkeypatch.setattr(train_mod, "environment_info", lambda: {"git_commit": f"after-{saves['n']}-saves"})
    log_file = tmp_path / "runs.jsonl"
    common = ("stage2.train.checkpoint_every=1000", f"stage2.train.run_log={log_file}")
    straight, cut = tmp_path / "straight", tmp_path / "cut"
    train(tiny_cfg(dataset, straight, *common, "stage2.train.checkpoint_minutes=null"), straight)
    assert saved_steps == [10]  # only the final one
    saved_steps.clear()
    cfg = tiny_cfg(dataset, cut, *common, "stage2.train.checkpoint_minutes=0")
    train(cfg, cut, stop_at=6)
    assert saved_steps == [1, 2, 3, 4, 5, 6]
    stats = train(cfg, cut)
    assert stats["resumed_from"] == 6 and stats["steps"] == 10 and stats["total_steps"] == 10
    a = torch.load(straight / "checkpoint.pt", weights_only=True)
    b = torch.load(cut / "checkpoint.pt", weights_only=True)
    for name, value in a["ema"].items():
        assert torch.equal(value, b["ema"][name]), name
    lines = [json.loads(x) for x in log_file.read_text().splitlines()]
    assert [(x["steps"], x["of"], x["done"]) for x in lines] == [([0, 10], 10, True), ([0, 6], 10, False),
                                                              ([6, 10], 10, True)]
    assert lines[-1]["out"] == f"<elsewhere>/{cut.parent.name}/{cut.name}" and lines[-1]["seed"] == 0  # no machine path
    assert [x["commit"] for x in lines] == ["after-0-saves", "after-1-saves", "after-7-saves"]


def stage2_on_test_scene(checkpoint: Path, dataset: Path):
    """(model, saved config, Stage I's cloud, predict): the checkpoint's model and the dataset's test
    scene with its views as Stage I's renders, unprojected; ``predict(**condition keys)`` runs Stage II
    inference on that cloud (2 DDIM steps, 300 points) and returns its [P, 5] PBR."""
    from eval.common.layout import read_splits
    from gspi.stage1.extract import unproject_renders
    from gspi.stage2.encoders import build_encoder
    from gspi.stage2.data import PointDataConfig
    from gspi.stage2.infer import InferenceConfig, predict_generated_points
    from tests.stage2_fixtures import gt_views_as_renders

    model, saved = load_stage2_checkpoint(checkpoint)
    renders = gt_views_as_renders(dataset / read_splits(dataset)["test"][0])
    points = unproject_renders(renders, alpha_threshold=0.5)
    encoder = build_encoder(saved["stage2"].prior)
    cfg = InferenceConfig(num_steps=2, max_points=300)

    def predict(**keys) -> np.ndarray:
        data = PointDataConfig(local_condition="top_rgb_onehot", **keys)
        return predict_generated_points(model, points, renders, data=data, encoder=encoder, cfg=cfg)[0]
    return model, saved, points, predict


def test_pixel_features_train_resume_and_infer(dataset, tmp_path):
    """stage2.data.pixel_features end to end: the model's condition is 35 + D wide, a resumed run
    equals an uninterrupted one, and Stage II inference on the test scene's views (as Stage I's
    renders) builds the same width; a caller that forgets the key is refused, naming it."""
    extra = ("stage2.data.pixel_features=true", "stage2.train.steps=4", "stage2.eval.enabled=false")
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    train(tiny_cfg(dataset, straight, *extra), straight)
    train(tiny_cfg(dataset, resumed, *extra), resumed, stop_at=2)
    train(tiny_cfg(dataset, resumed, *extra), resumed)
    a = torch.load(straight / "checkpoint.pt", weights_only=True)
    b = torch.load(resumed / "checkpoint.pt", weights_only=True)
    for name, value in a["ema"].items():
        assert torch.equal(value, b["ema"][name]), name
    model, saved, points, predict = stage2_on_test_scene(straight / "checkpoint.pt", dataset)
    assert saved["stage2"].data.pixel_features and model.config.local_cond_dim == 35 + 256
    pbr = predict(pixel_features=True)
    assert pbr.shape == (len(points), 5) and np.isfinite(pbr).all() and pbr.min() >= 0 and pbr.max() <= 1
    with pytest.raises(ValueError, match=r"291-dim local condition.*pixel_features=False, pixel_feature_spread=False\) gives 35"):
        predict()


def test_pixel_feature_spread_trains_and_infers(dataset, tmp_path):
    """stage2.data.pixel_feature_spread with pixel_features: the model's condition is 35 + 2 D
    wide, and Stage II inference (the test scene's views as Stage I's renders) builds that width."""
    out = tmp_path / "spread"
    train(tiny_cfg(dataset, out, "stage2.data.pixel_features=true", "stage2.data.pixel_feature_spread=true",
                   "stage2.train.steps=2", "stage2.eval.enabled=false"), out)
    model, saved, points, predict = stage2_on_test_scene(out / "checkpoint.pt", dataset)
    assert saved["stage2"].data.pixel_feature_spread and model.config.local_cond_dim == 35 + 2 * 256
    pbr = predict(pixel_features=True, pixel_feature_spread=True)
    assert pbr.shape == (len(points), 5) and np.isfinite(pbr).all()
    with pytest.raises(ValueError, match=r"547-dim local condition.*pixel_feature_spread=False\) gives 291"):
        predict(pixel_features=True)


def test_cross_view_radiance_trains_and_infers(dataset, tmp_path):
    """stage2.data.cross_view_radiance (issue 52): the model's condition is 35 + 5 wide, and
    Stage II inference on the test scene's views as Stage I's renders builds that width."""
    out = tmp_path / "radiance"
    train(tiny_cfg(dataset, out, "stage2.data.cross_view_radiance=true", "stage2.train.steps=2",
                   "stage2.eval.enabled=false"), out)
    model, saved, points, predict = stage2_on_test_scene(out / "checkpoint.pt", dataset)
    assert saved["stage2"].data.cross_view_radiance and model.config.local_cond_dim == 35 + 5
    pbr = predict(cross_view_radiance=True)
    assert pbr.shape == (len(points), 5) and np.isfinite(pbr).all()
    with pytest.raises(ValueError, match=r"40-dim local condition.*cross_view_radiance=False.*gives 35"):
        predict()


def test_cross_view_neighbourhood_trains_and_infers(dataset, tmp_path):
    """stage2.data.cross_view_neighbourhood (issue 52, session 26): + 16 after the statistic's 5, in
    training and in Stage II inference; a caller that leaves the key out is refused, naming it."""
    out = tmp_path / "neighbourhood"
    train(tiny_cfg(dataset, out, "stage2.data.cross_view_radiance=true", "stage2.data.cross_view_neighbourhood=true",
                   "stage2.train.steps=2", "stage2.eval.enabled=false"), out)
    model, saved, points, predict = stage2_on_test_scene(out / "checkpoint.pt", dataset)
    assert saved["stage2"].data.cross_view_neighbourhood and model.config.local_cond_dim == 35 + 5 + 16
    pbr = predict(cross_view_radiance=True, cross_view_neighbourhood=True)
    assert pbr.shape == (len(points), 5) and np.isfinite(pbr).all()
    with pytest.raises(ValueError, match=r"56-dim local condition.*cross_view_neighbourhood=False.*gives 40"):
        predict(cross_view_radiance=True)
