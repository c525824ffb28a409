"""Stage II recipes (conf/stage2/*.yaml): flat files whose composition never changed.

tests/golden/stage2_recipes.json holds every recipe and ablation as gspi-train composed it before
issue 53 flattened the chains; a flattened file must compose to exactly the same values.
"""
import json
from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from eval.config import register_configs

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
GOLDEN = json.loads((ROOT / "tests" / "golden" / "stage2_recipes.json").read_text())
FLAT = ["cpu_pool224_pixel_5k", "cpu_pool224_pixel", "cpu_pool224_5k", "cpu_pool224", "cpu_mix_pool",  # shipped recipes
        "cpu_matte_pool", "cpu_parts_pool", "cpu_pool_recon", "cpu_pool_trunc_snr", "cpu_pool_xs", "cpu_small",
        "table2_cpu"]  # (checkpoints/README.md) and Table 2's CPU recipe, rewritten flat by issue 53


# keys added after the golden was recorded, each off in every recipe (issue 52): (section, key) -> off value
ADDED_OFF = {("data", "cross_view_radiance"): False, ("data", "cross_view_neighbourhood"): False,
             ("data", "light_readout"): False, ("data", "light_wrong_share"): 0.0,
             ("data", "light_candidates"): "procedural", ("data", "light_env_height"): 64, ("data", "subset"): "local", ("inference", "patch_points"): None,
             ("inference", "patch_coverage"): 2.0}


def composed_stage2(override: str) -> dict:
    """The composed stage2 section without ``ADDED_OFF``'s keys, after checking they are off."""
    register_configs()
    with initialize_config_dir(version_base="1.3", config_dir=str(CONF)):
        cfg = OmegaConf.to_container(compose("gspi_train", overrides=[override]).stage2, resolve=True)
    for (section, key), off in ADDED_OFF.items():
        assert cfg[section].pop(key) == off, f"{override}: stage2.{section}.{key} is not off"
    return cfg


def run_default_recipe() -> str:
    """The stage2 option conf/gspi_run.yaml selects."""
    for entry in yaml.safe_load((CONF / "gspi_run.yaml").read_text())["defaults"]:
        if isinstance(entry, dict) and "stage2" in entry:
            return entry["stage2"]
    raise AssertionError("conf/gspi_run.yaml selects no stage2 option")


@pytest.mark.parametrize("name", sorted(GOLDEN["recipes"]))
def test_every_recipe_composes_as_before(name):
    assert composed_stage2(f"stage2={name}") == GOLDEN["recipes"][name]


@pytest.mark.parametrize("name", sorted(GOLDEN["ablations"]))
def test_every_ablation_composes_as_before(name):
    assert composed_stage2(f"ablation={name}") == GOLDEN["ablations"][name]


@pytest.mark.parametrize("name", FLAT)
def test_a_flat_recipe_has_one_level_of_defaults(name):
    defaults = yaml.safe_load((CONF / "stage2" / f"{name}.yaml").read_text())["defaults"]
    assert defaults == ["default", "_self_"]
    assert "defaults" not in yaml.safe_load((CONF / "stage2" / "default.yaml").read_text())


def test_the_run_default_is_flat():
    assert run_default_recipe() in FLAT


def test_every_recipe_that_names_a_shipped_checkpoint_is_flat():
    shipping = [p.stem for p in sorted((CONF / "stage2").glob("*.yaml"))
                if (yaml.safe_load(p.read_text()) or {}).get("checkpoint")]
    assert shipping and set(shipping) <= set(FLAT), sorted(set(shipping) - set(FLAT))
