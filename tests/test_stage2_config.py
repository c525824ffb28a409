"""Stage II's config dataclass (gspi/stage2/config.py): one set of defaults, equal to
conf/stage2/default.yaml; every key checked at start-up; older checkpoints completed."""
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dataclasses import asdict

from gspi.stage2.config import DERIVED_MODEL_KEYS, MODEL_KEYS, Stage2Config, complete_stage2, stored_config

CONF = str(Path(__file__).resolve().parents[1] / "conf")
ROOT = Path(__file__).resolve().parents[1]
SHIPPED_DEFAULT = "checkpoints/stage2_pool224_pixel_5k.pt"  # gspi-run's model (conf/stage2/cpu_pool224_pixel_5k.yaml)


def composed(*overrides, name="gspi_train"):
    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        return OmegaConf.to_container(compose(name, overrides=list(overrides)).stage2, resolve=True)


def test_default_yaml_equals_the_dataclass_defaults():
    assert composed() == asdict(complete_stage2({}))


SHIPPED = sorted([[f"stage2={p.stem}"] for p in (ROOT / "conf" / "stage2").glob("*.yaml")]
                 + [[f"ablation={p.stem}"] for p in (ROOT / "conf" / "ablation").glob("a[1-5]_*.yaml")])


@pytest.mark.parametrize("overrides", SHIPPED, ids=lambda o: o[0])
def test_every_shipped_stage2_config_is_complete_and_valid(overrides):
    node = composed(*overrides)
    assert asdict(complete_stage2(node)) == node  # nothing missing, nothing unknown


def test_a_missing_key_gets_its_default_and_a_set_one_is_kept():
    full = complete_stage2({"train": {"lr": 0.5}, "model": {"num_heads": 4, "latent_dim": 96, "point_dim": 64}})
    assert full.train.lr == 0.5 and full.train.min_lr_ratio == 0.1
    assert full.model["num_heads"] == 4 and full.model["num_latents"] == 256
    assert set(full.model) == set(MODEL_KEYS)
    assert asdict(full.prior.alexnet) == {"layer": "relu5", "input_size": 224}
    assert complete_stage2(full) is full  # a checked config is passed on, not parsed again


@pytest.mark.parametrize("node, message", [
    ({"train": {"lrr": 1e-3}}, r"stage2\.train\.lrr"),
    ({"train": {"batch_size": "8"}}, r"stage2\.train\.batch_size='8': must be an integer"),
    ({"train": {"batch_size": 0}}, r"stage2\.train\.batch_size=0: must be an integer >= 1"),
    ({"diffusion": {"prediction": "v"}}, r"stage2\.diffusion\.prediction='v': must be one of \['eps', 'x0', 'x0_readout'\]"),
    ({"prior": {"encoder": "clip"}}, "alexnet, dinov2, none"),
    ({"prior": {"alexnet": {"layer": "fc7"}}}, "relu5"),
    ({"data": {"local_condition": "depth"}}, r"local_condition='depth'"),
    ({"data": {"pixel_features": True}, "prior": {"encoder": "none"}}, r"pixel_features .*not none"),
    ({"data": {"pixel_feature_spread": True}, "prior": {"encoder": "none"}}, r"pixel_feature_spread .*not none"),
    ({"model": {"local_cond_dim": 3}}, r"stage2\.model\.local_cond_dim is derived"),
    ({"model": {"latent_dim": 100, "num_heads": 8}}, "not divisible"),
    ({"model": {"num_blocks": 2.5}}, r"stage2\.model\.num_blocks=2\.5"),
    ({"eval": {"split": "dev"}}, r"stage2\.eval\.split='dev'"),
    ({"train": {"betas": [0.9]}}, r"stage2\.train\.betas"),
    ({"inference": {"num_stepz": 5}}, r"stage2\.inference\.num_stepz"),
])
def test_bad_values_are_refused_naming_the_key(node, message):
    with pytest.raises(ValueError, match=message):
        Stage2Config.from_dict(node)


def test_gspi_run_checks_stage2_at_start_up():
    from gspi.run.config_check import check_run_config

    with pytest.raises(ValueError, match=r"stage2\.train\.lr='fast'"):
        check_run_config({"split": "test", "data_dir": "d", "out": "o",
                          "stage2": {"train": {"lr": "fast"}}})


def test_derived_keys_are_rcw_fields_and_disjoint_from_the_sizes():
    from dataclasses import fields

    from gspi.stage2.model import RCWConfig
    names = {f.name for f in fields(RCWConfig)}
    assert set(DERIVED_MODEL_KEYS) <= names and set(MODEL_KEYS) == names - set(DERIVED_MODEL_KEYS)


def test_an_older_checkpoint_config_is_completed_on_load(tmp_path):
    """A checkpoint saved before a key existed (here: prediction, min_lr_ratio, log_every)
    loads with that key's default, so no reader needs a .get(key, default)."""
    from gspi.stage2.checkpoint import load_stage2_checkpoint

    ckpt = torch.load(ROOT / SHIPPED_DEFAULT, weights_only=False)
    stage2 = ckpt["config"]["stage2"]
    del stage2["train"]["min_lr_ratio"], stage2["train"]["log_every"], stage2["eval"]
    torch.save(ckpt, tmp_path / "old.pt")
    _, cfg = load_stage2_checkpoint(tmp_path / "old.pt")
    assert isinstance(cfg["stage2"], Stage2Config)
    assert cfg["stage2"].train.min_lr_ratio == 0.1 and cfg["stage2"].train.log_every == 100
    assert cfg["stage2"].eval.num_steps == 50
    assert cfg["stage2"].diffusion.prediction == "x0"  # what it was saved with is kept
    stored = stored_config(cfg)  # plain data again, as a checkpoint writes it
    assert stored["stage2"]["eval"]["num_steps"] == 50 and complete_stage2(stored["stage2"]) == cfg["stage2"]


def test_a_checkpoint_with_an_invalid_stored_config_names_the_file(tmp_path):
    from gspi.stage2.checkpoint import CheckpointError, load_stage2_checkpoint

    ckpt = torch.load(ROOT / SHIPPED_DEFAULT, weights_only=False)
    ckpt["config"]["stage2"]["train"]["no_such_key"] = 1
    torch.save(ckpt, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match=r"bad\.pt.*stage2\.train\.no_such_key"):
        load_stage2_checkpoint(tmp_path / "bad.pt")


@pytest.mark.parametrize("key", ["stop_after_minutes", "stop_after_cpu_minutes"])
def test_gspi_run_refuses_a_time_budget_for_the_model_it_trains(key):
    """gspi-run caches its trained Stage II model by config: a time budget would make it
    machine-dependent (and a budget-stopped run never "finished"); a given checkpoint is fine."""
    from gspi.run.config_check import check_run_config

    cfg = {"split": "test", "data_dir": "d", "out": "o",
           "stage2": {"checkpoint": None, "train": {key: 15}}}
    with pytest.raises(ValueError, match=rf"stage2\.train\.{key}=15: gspi-run trains Stage II to "
                                         r"stage2\.train\.steps"):
        check_run_config(cfg)
    check_run_config({**cfg, "stage2": {**cfg["stage2"], "checkpoint": SHIPPED_DEFAULT}})
    check_run_config({**cfg, "stage2": {"checkpoint": None, "train": {key: None}}})


XS_PARAMETERS = 349141  # Table 2's XS model with the 35-dim local condition
PIXEL_PARAMETERS = XS_PARAMETERS + 256 * 48  # + 256 pixel-feature inputs x the point stream width (point_dim 48)


@pytest.mark.parametrize("name, preset, steps, parameters", [
    ("stage2_pool224_pixel_5k", "cpu_pool224_pixel_5k", 5000, PIXEL_PARAMETERS)])  # the retired ones are tested in their study
def test_the_shipped_pool_checkpoints_are_their_recipes(name, preset, steps, parameters):
    """checkpoints/<name>.pt loads, is under 20 MB, is what conf/stage2/<preset>.yaml trains (the
    truncated-SNR weight, the recipe's steps and sizes) and is the file its json card hashes."""
    import hashlib
    import json

    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR
    from gspi.stage2.checkpoint import load_stage2_checkpoint

    path = ROOT / "checkpoints" / f"{name}.pt"
    assert path.stat().st_size < 20e6
    card = json.loads(path.with_suffix(".json").read_text())
    assert card["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest() and card["size_bytes"] == path.stat().st_size
    model, cfg = load_stage2_checkpoint(path)
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        recipe = compose("gspi_train", overrides=[f"stage2={preset}", "data_dir=d", "out=o"])
    assert recipe.stage2.checkpoint == f"checkpoints/{name}.pt"
    stage2 = cfg["stage2"]
    assert stage2.diffusion.min_snr_floor == 1.0 and stage2.diffusion.prediction == "x0"
    assert stage2.train.steps == recipe.stage2.train.steps == steps
    assert stage2.model == {k: recipe.stage2.model[k] for k in stage2.model}
    assert stage2.data.pixel_features == recipe.stage2.data.pixel_features == (parameters != XS_PARAMETERS)
    assert not model.training and sum(p.numel() for p in model.parameters()) == card["parameters"] == parameters
