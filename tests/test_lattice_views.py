"""Lattice-view evaluation (`eval.split=lattice` = the scenes' `train` views) for every method:
the evaluator, gspi-run's in-house methods and the external adapters (issue 14 item 6)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from omegaconf import OmegaConf

from baselines.adapter import AdapterError, get_adapter, load_method_config
from eval.evaluate import evaluate
from eval.common.layout import LayoutError, read_scene, read_view_file
from eval.protocol_id import describe_protocol, protocol_dict, protocol_hash, scored_split
from tests.adapter_fixtures import q8, save_image, srgb_eotf, srgb_oetf
from tests.fixtures import make_prediction, make_scene, protocol


def test_lattice_scores_the_train_views_with_a_known_error(sphere_dataset, tmp_path, lpips_net):
    """Roughness + 6554/65535 inside the mask on the 2 train views of 2 scenes: every image
    scores exactly -10 log10(offset^2); `lattice` and `train` are one protocol (one hash)."""
    offset = 6554 / 65535
    pred = make_prediction(sphere_dataset, tmp_path / "pred", roughness_offset=offset, split="train",
                           channels=("roughness",))
    lattice = protocol(split="lattice", channels=["roughness"])
    result = evaluate(sphere_dataset, pred, lattice, net=lpips_net)
    assert [(r["scene"], r["view"]) for r in result.rows] == [
        ("sphere_0", "000"), ("sphere_0", "001"), ("sphere_1", "000"), ("sphere_1", "001")]
    for row in result.rows:
        assert row["psnr"] == pytest.approx(-10 * math.log10(offset ** 2), abs=1e-6)
    assert scored_split(lattice) == "train"
    as_train = protocol_dict(protocol(split="train", channels=["roughness"]))
    assert protocol_hash(protocol_dict(lattice)) == protocol_hash(as_train)
    assert protocol_hash(protocol_dict(lattice)) != protocol_hash(protocol_dict(protocol(channels=["roughness"])))
    assert "split train (lattice views)" in describe_protocol(protocol_dict(lattice))
    assert "split test;" in describe_protocol(protocol_dict(protocol()))


def test_test_view_predictions_are_not_scored_as_lattice_views(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred")  # test views only
    with pytest.raises(LayoutError, match=r"0 images scored. Looked for .*/train/<view>/"):
        evaluate(sphere_dataset, pred, protocol(split="lattice"), net=lpips_net)


def test_a_split_typo_lists_the_allowed_values():
    with pytest.raises(ValueError, match=r"eval.split='latice'; allowed: test, lattice, train, val"):
        protocol(split="latice")


# ----------------------------------------------------------------------------- gspi-run

def test_gspi_run_predicts_and_scores_the_lattice_views(micro_dataset, tmp_path):
    """`eval.split=lattice`: each in-house method writes and scores the scene's train views
    (none of its test views); `split` still picks the dataset's (test) scenes."""
    from gspi.run.runner import run_job
    from tests.run_helpers import run_config

    scene_name = json.loads((micro_dataset / "splits.json").read_text())["test"][0]
    scene = read_scene(micro_dataset / scene_name)
    for method in ("no_decomposition", "joint_ir", "gspi"):
        out = tmp_path / method
        extra = [f"method={method}", "eval.split=lattice", "figures=false"]
        if method == "joint_ir":
            extra += ["method.iterations=2", "method.views_per_iteration=1"]
        result = run_job(run_config(micro_dataset, out, extra))
        assert result["status"] == "complete" and result["scenes"] == [scene_name], result
        pred = out / "predictions" / scene_name
        assert sorted(p.name for p in pred.iterdir() if p.is_dir()) == ["train"], method
        assert sorted(p.name for p in (pred / "train").iterdir()) == [v.id for v in scene.split_views("train")]
        meta = json.loads((out / "eval" / "eval_meta.json").read_text())
        assert meta["protocol_config"]["split"] == "lattice"
        assert meta["counts"]["albedo"]["images"] == len(scene.split_views("train")), method


# ----------------------------------------------------------------------------- adapters

@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene(tmp_path_factory.mktemp("gt"), "ball", size=20, seed=1, num_train=2, num_test=3)


def train_maps(scene):
    out = []
    for v in scene.split_views("train"):
        d = scene.view_dir("train", v.id)
        out.append({"albedo": read_view_file(d, "albedo.png").astype(np.float64),
                    "roughness": read_view_file(d, "roughness.png")[..., 0].astype(np.float64)})
    return out


def test_irgs_imports_its_train_renders_as_the_lattice_views(scene, tmp_path):
    """IRGS's render.py (recipe: no --skip_train) writes irgs/train/ours_<iter>/ in the exported
    frame order; split=train imports train view k from index k."""
    maps = train_maps(scene)
    train = tmp_path / "model" / "irgs" / "train" / "ours_20000"
    for k, m in enumerate(maps):
        save_image(train / "base_color_linear" / f"{k:05d}.png", srgb_eotf(m["albedo"]))
        save_image(train / "roughness" / f"{k:05d}.png", m["roughness"])
    pred = get_adapter("irgs").import_outputs(tmp_path / "model", scene.root, tmp_path / "pred",
                                              load_method_config("irgs"), split="train")
    assert sorted(p.name for p in pred.iterdir() if p.is_dir()) == ["train"]
    for view, m in zip(scene.split_views("train"), maps):
        vdir = pred / "train" / view.id
        np.testing.assert_allclose(read_view_file(vdir, "albedo.png"), srgb_oetf(q8(srgb_eotf(m["albedo"]))),
                                   rtol=0, atol=0.5 / 65535 + 1e-7)
        np.testing.assert_allclose(read_view_file(vdir, "roughness.png")[..., 0], q8(m["roughness"]),
                                   rtol=0, atol=0.5 / 65535 + 1e-7)
    with pytest.raises(AdapterError, match=r"model/irgs/test, .*model/test exists"):
        get_adapter("irgs").import_outputs(tmp_path / "model", scene.root, tmp_path / "p2",
                                           load_method_config("irgs"))  # test views were not rendered
    with pytest.raises(AdapterError, match=r"irgs: its commands render the train and test views only, not 'val'"):
        get_adapter("irgs").import_outputs(tmp_path / "model", scene.root, tmp_path / "p3",
                                           load_method_config("irgs"), split="val")


def test_gs_ir_renders_the_lattice_views_only_when_asked(scene, tmp_path):
    adapter, cfg = get_adapter("gs_ir"), load_method_config("gs_ir")
    render = adapter.commands(tmp_path / "data", tmp_path / "model", cfg)[-1]
    assert "--skip_train" in render
    render = adapter.commands(tmp_path / "data", tmp_path / "model", {**cfg, "render_lattice": True})[-1]
    assert "--skip_train" not in render and "--pbr" in render
    with pytest.raises(ValueError, match=r"render_lattice='yes'; allowed: True, False"):
        adapter.commands(tmp_path / "data", tmp_path / "model", {**cfg, "render_lattice": "yes"})
    (tmp_path / "model" / "test" / "ours_None").mkdir(parents=True)
    with pytest.raises(AdapterError, match=r"model/train/ours_None: missing folder .*method.render_lattice=true"):
        adapter.import_outputs(tmp_path / "model", scene.root, tmp_path / "pred", cfg, split="train")
    lumi = get_adapter("lumigauss")
    lcfg = load_method_config("lumigauss")
    assert "--skip_train" in lumi.commands(tmp_path / "d", tmp_path / "m", lcfg)[-1]
    assert "--skip_train" not in lumi.commands(tmp_path / "d", tmp_path / "m", {**lcfg, "render_lattice": True})[-1]


def test_gspi_import_split_option_is_validated(scene, tmp_path):
    from baselines.cli import run_import

    cfg = OmegaConf.create({"method": load_method_config("irgs"), "src": str(tmp_path), "scene": str(scene.root),
                            "out": str(tmp_path / "pred"), "runtime_s": None, "split": "lattise"})
    with pytest.raises(ValueError, match=r"split='lattise'; allowed for irgs: train, test, lattice"):
        run_import(cfg)


def test_gspi_run_imports_an_external_systems_lattice_views(micro_dataset, tmp_path):
    """IRGS outputs of the train views placed under method.outputs: gspi-run eval.split=lattice
    imports and scores them; a runtime given as {geometry, material} reaches meta.json."""
    from gspi.run.runner import run_job
    from tests.run_helpers import run_config

    name = json.loads((micro_dataset / "splits.json").read_text())["test"][0]
    scene = read_scene(micro_dataset / name)
    train = tmp_path / "outputs" / name / "irgs" / "train" / "ours_20000"
    for k, m in enumerate(train_maps(scene)):
        save_image(train / "base_color_linear" / f"{k:05d}.png", srgb_eotf(m["albedo"]))
        save_image(train / "roughness" / f"{k:05d}.png", m["roughness"])
    out = tmp_path / "run"
    result = run_job(run_config(micro_dataset, out, [
        "method=irgs", f"method.outputs={tmp_path / 'outputs'}", "eval.split=lattice", "figures=false",
        "method.runtime_s={geometry: 600, material: 400}"]))
    assert result["status"] == "complete", result
    meta = json.loads((out / "predictions" / name / "meta.json").read_text())
    assert meta["runtime_s"] == {"material": 400.0, "end_to_end": 1000.0, "geometry": 600.0}
    summary = json.loads((out / "eval" / "summary.json").read_text())
    assert summary["albedo"]["psnr"] > 40 and summary["roughness"]["psnr"] > 40  # GT through 8 bits
    eval_meta = json.loads((out / "eval" / "eval_meta.json").read_text())
    assert eval_meta["counts"]["albedo"]["images"] == len(scene.split_views("train"))
    assert eval_meta["runtime_min"] == {"material": 400 / 60, "end_to_end": 1000 / 60, "geometry": 10.0}
