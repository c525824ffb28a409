"""The learnability ladder's rungs (experiments/ladder/ladder.py, regressors.py): each trains on a
fixed batch, is saved and loaded back, and is scored with Table 2's measure."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from gspi.stage2.checkpoint import CheckpointError
from gspi.stage2.encoders import build_encoder
from experiments.ladder.ladder import (build_rung, ladder_config, load_rung, predict_rung, rung_loss, save_rung,
                                score_rung)
from experiments.ladder.regressors import pooled_prior, rung_features
from gspi.stage2.splits import load_split
from tests.stage2_fixtures import make_lattice_dataset

RUNGS = ("r1", "r2", "r3", "r4")


@pytest.fixture(scope="module")
def ladder_data(tmp_path_factory):
    root = make_lattice_dataset(tmp_path_factory.mktemp("ladder"), num_train=2, num_test=1)
    cfg = ladder_config(root, seed=0, overrides=("stage2.data.num_points=128", "stage2.train.batch_size=2"))
    scenes = load_split(cfg, "train", build_encoder(cfg["stage2"].prior))
    return root, cfg, scenes, int(pooled_prior(scenes[0]).shape[0])


@pytest.mark.parametrize("rung", RUNGS)
def test_rung_loss_is_finite_and_falls_on_a_fixed_batch(ladder_data, rung):
    _, cfg, scenes, prior_dim = ladder_data
    torch.manual_seed(0)
    model = build_rung(rung, cfg, prior_dim)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    data_cfg = cfg["stage2"].data
    losses = []
    for _ in range(15):
        loss = rung_loss(model, rung, scenes, data_cfg, 2, np.random.default_rng(7))  # the same batch
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert np.isfinite(losses).all()
    assert losses[-1] < 0.7 * losses[0]


def test_rung_features_widths():
    assert rung_features("r1").width(256) == 35
    assert rung_features("r2").width(256) == 35 + 256
    assert rung_features("r3").width(256) == 35 + 128
    with pytest.raises(ValueError, match="not a per-point MLP rung"):
        rung_features("r4")


@pytest.mark.parametrize("rung", ["r2", "r4"])
def test_saved_rung_loads_and_predicts_the_same(ladder_data, rung, tmp_path):
    _, cfg, scenes, prior_dim = ladder_data
    torch.manual_seed(1)
    model = build_rung(rung, cfg, prior_dim).eval()
    path = save_rung(model, rung, cfg, {"prior_dim": prior_dim}, tmp_path / "model.pt")
    loaded, name, _ = load_rung(path)
    data_cfg = cfg["stage2"].data
    a = predict_rung(model, rung, scenes[0], 0, data_cfg)
    b = predict_rung(loaded, name, scenes[0], 0, data_cfg)
    assert name == rung and a.shape == (scenes[0].num_points, 5)
    np.testing.assert_array_equal(a, b)
    assert (a >= 0).all() and (a <= 1).all()


def test_load_rung_names_the_file(tmp_path):
    bad = tmp_path / "other.pt"
    torch.save({"format": "something else"}, bad)
    with pytest.raises(CheckpointError, match="other.pt: not a ladder model"):
        load_rung(bad)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_rung(tmp_path / "missing.pt")


def test_score_rung_writes_table2_measure_with_metal_iou(ladder_data, tmp_path, lpips_net):
    root, cfg, _, prior_dim = ladder_data
    model = build_rung("r1", cfg, prior_dim).eval()
    result = score_rung(model, "r1", cfg, root, "test", tmp_path / "eval", baseline_train=root,
                        train_stats={"steps": 0})
    assert (tmp_path / "eval" / "scores.json").is_file()
    assert set(result["mean"]) == {"stage2", "no_decomposition"}
    assert result["ablation"] == "r1" and set(result["metal_iou"]["stage2"]) == {"test_0"}


def _scores(folder, rung, seed, values, ladder=True):
    """A scores.json of two scenes: a metal one and a fabric one, PSNR per channel from `values`."""
    import json

    def scene(a, r, m):
        return {"albedo": {"psnr": a}, "roughness": {"psnr": r}, "metallic": {"psnr": m}}
    data = {"ablation": rung, "train_seed": seed,
            "per_scene": {"stage2": {"p1_blob_metal": scene(*values[0]), "p2_torus_fabric": scene(*values[1])},
                          "no_decomposition": {"p1_blob_metal": scene(10, 10, 4), "p2_torus_fabric": scene(12, 10, 60)}},
            "metal_iou": {"stage2": {"p1_blob_metal": 0.5, "p2_torus_fabric": None},
                          "no_decomposition": {"p1_blob_metal": None, "p2_torus_fabric": None}}}
    if ladder:
        data["ladder"] = {}
    folder.mkdir(parents=True)
    (folder / "scores.json").write_text(json.dumps(data))
    return folder


def test_summary_pools_seeds_and_reports_metal(tmp_path):
    from experiments.ladder.ladder_summary import summarise, to_markdown

    folders = [_scores(tmp_path / "a", "r1", 0, [(10, 20, 6), (14, 20, 30)]),
               _scores(tmp_path / "b", "r1", 1, [(12, 20, 9), (14, 22, 30)]),
               _scores(tmp_path / "c", "full", 0, [(11, 21, 20), (13, 21, 40)], ladder=False)]
    s = summarise(folders)
    assert set(s) == {"r1", "r5", "no_decomposition"}
    # per seed avg: seed 0 (12 + 20 + 18) / 3 = 16.667, seed 1 (13 + 21 + 19.5) / 3 = 17.833
    assert s["r1"]["spread"] == pytest.approx(17.8333 - 16.6667, abs=1e-3)
    assert s["r1"]["mean"]["metallic@metal"] == pytest.approx(7.5)
    assert s["r1"]["mean"]["metal_iou@metal"] == pytest.approx(0.5)
    assert s["no_decomposition"]["mean"]["metal_iou@metal"] == 0.0   # no metal predicted: IoU 0
    assert s["r5"]["seeds"] == [0]
    assert "| R0 no decomposition | 1 |" in to_markdown(s)
    from experiments.ladder.ladder_summary import versus

    d = versus(folders, "r1")  # avg over channels, paired over (scene, seed); hand-computed
    assert d["r5"][0] == pytest.approx((52 / 3 - 12 + 74 / 3 - 64 / 3) / 2)
    assert d["no_decomposition"][0] == pytest.approx((8 - 12 + 8 - 41 / 3 + 82 / 3 - 64 / 3 + 82 / 3 - 22) / 4)
    mean, lo, hi = versus(folders, "r1", "metallic", "metal")["r5"]  # one metal scene, one seed
    assert mean == 14.0 and np.isnan(lo) and np.isnan(hi)


def test_point_metal_iou(ladder_data):
    from gspi.stage2.points_measure import point_metal_iou
    from gspi.stage2.normalize import pbr_from_model

    _, _, scenes, _ = ladder_data
    scene = scenes[0]
    gt = pbr_from_model(torch.from_numpy(scene.f0[:, 4])).numpy()
    if (gt > 0.5).any():
        assert point_metal_iou(gt, scene) == 1.0
        assert point_metal_iou(np.zeros_like(gt), scene) == 0.0
    else:
        assert point_metal_iou(np.zeros_like(gt), scene) is None
        assert point_metal_iou(np.ones_like(gt), scene) == 0.0


def test_rung_of_a_diffusion_run_is_its_folder_name():
    from experiments.ladder.ladder_summary import rung_of

    assert rung_of({"ladder": {}, "ablation": "r3"}) == "r3"
    assert rung_of({"ablation": "full", "checkpoint": "/x/runs/r5skip_s2/checkpoint.pt"}) == "r5skip"
    assert rung_of({"ablation": "full", "checkpoint": "/x/runs/t2cpu/full/checkpoint.pt"}) == "r5"
    assert rung_of({"ablation": "full", "checkpoint": "/x/runs/r6skip_s1/checkpoint.pt"}) == "r6skip"
    assert rung_of({"ablation": "full", "checkpoint": "/x/runs/rerun_s1/checkpoint.pt"}) == "r5"
