"""Validation during Stage II training (gspi/stage2/validate.py): scores in metrics.jsonl, the
best EMA weights as best.pt, and training unchanged by it (tiny sizes, 1 thread)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gspi.stage2.checkpoint import load_stage2_checkpoint
from gspi.stage2.train import train
from gspi.stage2.train_log import JsonlMetrics
from gspi.stage2.validate import SCORE_KEY
from tests.stage2_fixtures import lattice_dataset, tiny_cfg  # noqa: F401  (fixture `dataset`)

VALIDATE = ("stage2.validate.every=4", "stage2.validate.split=test", "stage2.validate.num_steps=2",
            "stage2.validate.max_points=300")


@pytest.fixture(scope="module")
def runs(dataset, tmp_path_factory):
    root = tmp_path_factory.mktemp("s2val")
    plain, checked = root / "plain", root / "checked"
    train(tiny_cfg(dataset, plain), plain)
    stats = train(tiny_cfg(dataset, checked, *VALIDATE), checked)
    return plain, checked, stats


def test_validation_does_not_change_training(runs):
    plain, checked, _ = runs
    a = torch.load(plain / "checkpoint.pt", weights_only=True)
    b = torch.load(checked / "checkpoint.pt", weights_only=True)
    for key in ("model", "ema"):
        for name, value in a[key].items():
            assert torch.equal(value, b[key][name]), f"{key}.{name} differs with validation on"


def test_scores_are_logged_at_the_due_steps_and_best_is_kept(runs):
    _, checked, stats = runs
    steps, scores = JsonlMetrics(checked / "metrics.jsonl").series(SCORE_KEY)
    assert steps.tolist() == [4, 8, 10]  # every 4 steps and the last of 10
    assert np.isfinite(scores).all() and (scores > 0).all()
    best = int(np.argmax(scores))
    assert stats["best_validation"] == {"step": int(steps[best]), "score": pytest.approx(scores[best])}
    model, cfg = load_stage2_checkpoint(checked / "best.pt")
    saved = torch.load(checked / "best.pt", weights_only=True)
    assert saved["step"] == steps[best] and "optimizer" not in saved and not model.training
    assert cfg["stage2"].validate.every == 4


def test_validation_scores_are_reproducible(dataset, runs, tmp_path):  # noqa: F811
    """A resumed run logs the same validation scores as an uninterrupted one."""
    _, checked, _ = runs
    cfg = tiny_cfg(dataset, tmp_path, *VALIDATE)
    train(cfg, tmp_path, stop_at=6)  # validates at 4 and, stopping, at 6
    train(cfg, tmp_path)
    want = JsonlMetrics(checked / "metrics.jsonl").series(SCORE_KEY)
    got = JsonlMetrics(tmp_path / "metrics.jsonl").series(SCORE_KEY)
    # the resumed file keeps step 6's extra validation (logged before the checkpoint at 6)
    keep = got[0] != 6
    assert got[0][keep].tolist() == want[0].tolist()
    np.testing.assert_allclose(got[1][keep], want[1], rtol=0, atol=1e-9)


def test_an_empty_validation_split_is_refused(dataset, tmp_path):  # noqa: F811
    cfg = tiny_cfg(dataset, tmp_path, "stage2.validate.every=2", "stage2.validate.split=val")
    with pytest.raises(ValueError, match="split 'val' is empty"):
        train(cfg, tmp_path)


def test_evaluate_points_with_max_points_is_the_validation_measure(dataset, runs, tmp_path):  # noqa: F811
    """One prediction path: evaluate_points with --max-points scores best.pt exactly as the
    validation did, and without it predicts every point (another, recorded measure)."""
    from eval.points_protocol import MeasureError
    from gspi.stage2.evaluate_points import checkpoint_source, evaluate_checkpoint

    _, checked, stats = runs
    model, cfg = load_stage2_checkpoint(checked / "best.pt")
    sub = evaluate_checkpoint(model, cfg, dataset, tmp_path / "sub", split="test", num_steps=2, seed=0,
                              max_points=300, source=checkpoint_source(checked / "best.pt"))
    assert sub["mean"]["stage2"]["avg"]["psnr"] == pytest.approx(stats["best_validation"]["score"], abs=1e-9)
    assert (sub["max_points"], sub["checkpoint_step"]) == (300, stats["best_validation"]["step"])
    full = evaluate_checkpoint(model, cfg, dataset, tmp_path / "all", split="test", num_steps=2, seed=0)
    assert full["max_points"] is None
    with pytest.raises(MeasureError, match="told_light=other: this model reads no light"):
        evaluate_checkpoint(model, cfg, dataset, tmp_path / "wrong", split="test", told_light="other")
    assert full["mean"]["stage2"]["avg"]["psnr"] != pytest.approx(sub["mean"]["stage2"]["avg"]["psnr"], abs=1e-6)
    assert full["mean"]["no_decomposition"] == sub["mean"]["no_decomposition"]


def test_evaluate_points_baseline_constants_from_another_dataset(dataset, runs, tmp_path):  # noqa: F811
    """A test-only dataset: its empty train split is named with the remedy; --baseline-train
    takes the constants from another dataset (here the same one: the same scores)."""
    import json
    import shutil

    from gspi.stage2.evaluate_points import main

    _, checked, _ = runs
    test_only = tmp_path / "test_only"
    splits = json.loads((dataset / "splits.json").read_text())
    test_only.mkdir()
    for name in splits["test"]:
        shutil.copytree(dataset / name, test_only / name)
    (test_only / "splits.json").write_text(json.dumps({"train": [], "val": [], "test": splits["test"]}))
    args = [str(checked / "best.pt"), str(test_only), str(tmp_path / "a"), "--num-steps", "2", "--max-points", "300"]
    with pytest.raises(ValueError, match=r"split 'train' is empty: the no-decomposition baseline.*--baseline-train"):
        main(args)
    main(args + ["--baseline-train", str(dataset)])
    main([str(checked / "best.pt"), str(dataset), str(tmp_path / "b"), "--num-steps", "2", "--max-points", "300"])
    a, b = (json.loads((tmp_path / k / "scores.json").read_text()) for k in "ab")
    assert a["per_scene"] == b["per_scene"] and a["baseline_constants"] == b["baseline_constants"]
    assert a["baseline_train"] == str(dataset.resolve())
    # what each measure read, by checksum: a copy's bytes are the same wherever it lives ...
    assert a["checksums"] == b["checksums"] and sorted(a["checksums"]["per_scene"]) == sorted(splits["test"])
    # ... and one changed byte of one scene changes that scene's checksum and the overall one, only
    from gspi.stage2.evaluate_points import scene_inputs_checksums

    scene = splits["test"][0]
    npz = test_only / scene / "gt_points.npz"
    data = bytearray(npz.read_bytes())
    data[-1] ^= 1
    npz.write_bytes(bytes(data))
    changed = scene_inputs_checksums(test_only, splits["test"])
    assert changed["inputs"] != a["checksums"]["inputs"]
    assert [n for n in splits["test"] if changed["per_scene"][n] != a["checksums"]["per_scene"][n]] == [scene]



def test_num_samples_averages_the_single_seed_predictions(dataset, runs):  # noqa: F811
    """--num-samples K predicts, on the cloud perturbed by ``seed``, the mean of K DDIM samples
    with noise seeds seed..seed+K-1 (gspi-run's stage2.inference.num_samples); K=1 is one sample."""
    from gspi.stage2.encoders import build_encoder
    from gspi.stage2.points_measure import PointSampling, subset_prediction, whole_scene_inputs
    from gspi.stage2.sampler import predict_point_pbr
    from gspi.stage2.splits import load_split

    _, checked, _ = runs
    model, cfg = load_stage2_checkpoint(checked / "best.pt")
    scene = load_split({**cfg, "data_dir": str(dataset)}, "test", build_encoder(cfg["stage2"].prior))[0]
    data_cfg = cfg["stage2"].data
    xyz, cond = whole_scene_inputs(scene, data_cfg, np.random.default_rng([0, 0]))
    feats = scene.prior_grid()
    samples = [predict_point_pbr(model, xyz, cond, feats, num_steps=2, seed=k, frame=scene.frame).numpy()
               for k in range(3)]

    def measured(k: int) -> np.ndarray:
        return subset_prediction(model, scene, 0, data_cfg, PointSampling(num_steps=2, seed=0, num_samples=k))
    np.testing.assert_array_equal(measured(1), samples[0])
    np.testing.assert_allclose(measured(3), np.mean(samples, axis=0), rtol=0, atol=1e-6)
    assert not np.allclose(samples[0], samples[1])  # the seeds do draw different samples


def test_guidance_scale_reaches_the_sampler(dataset, runs):  # noqa: F811
    """--guidance-scale s measures what predict_point_pbr samples with classifier-free guidance s
    (gspi-run's stage2.inference.guidance_scale), and s != 1 does change the prediction."""
    from gspi.stage2.encoders import build_encoder
    from gspi.stage2.points_measure import PointSampling, subset_prediction, whole_scene_inputs
    from gspi.stage2.sampler import predict_point_pbr
    from gspi.stage2.splits import load_split

    _, checked, _ = runs
    model, cfg = load_stage2_checkpoint(checked / "best.pt")
    scene = load_split({**cfg, "data_dir": str(dataset)}, "test", build_encoder(cfg["stage2"].prior))[0]
    data_cfg = cfg["stage2"].data
    xyz, cond = whole_scene_inputs(scene, data_cfg, np.random.default_rng([0, 0]))
    guided = predict_point_pbr(model, xyz, cond, scene.prior_grid(), num_steps=2, seed=0, frame=scene.frame,
                               guidance_scale=3.0).numpy()
    measured = subset_prediction(model, scene, 0, data_cfg, PointSampling(num_steps=2, seed=0, guidance_scale=3.0))
    np.testing.assert_array_equal(measured, guided)
    plain = subset_prediction(model, scene, 0, data_cfg, PointSampling(num_steps=2, seed=0))
    assert not np.allclose(plain, guided)
