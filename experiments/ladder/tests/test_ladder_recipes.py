"""The ladder's Stage II options (experiments/ladder/conf/stage2/) compose, with the study's conf on
gspi-train's search path, exactly as they did in conf/stage2 (golden_recipes.json)."""
import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from eval.config import CONF_DIR, register_configs

STUDY_CONF = Path(__file__).resolve().parents[1] / "conf"
GOLDEN = json.loads((Path(__file__).with_name("golden_recipes.json")).read_text())
# keys added after the golden was recorded, each off in every recipe (issue 52), as tests/test_stage2_recipes.py
ADDED_OFF = {("data", "cross_view_radiance"): False, ("data", "cross_view_neighbourhood"): False,
             ("data", "light_readout"): False, ("data", "light_wrong_share"): 0.0,
             ("data", "light_candidates"): "procedural", ("data", "light_env_height"): 64,
             ("data", "subset"): "local", ("inference", "patch_points"): None, ("inference", "patch_coverage"): 2.0}


@pytest.mark.parametrize("name", sorted(GOLDEN["recipes"]))
def test_the_ladder_recipe_composes_as_before(name):
    register_configs()
    with initialize_config_dir(version_base="1.3", config_dir=str(CONF_DIR)):
        cfg = compose("gspi_train", overrides=[f"hydra.searchpath=[file://{STUDY_CONF}]", f"stage2={name}"])
    stage2 = OmegaConf.to_container(cfg.stage2, resolve=True)
    for (section, key), off in ADDED_OFF.items():
        assert stage2[section].pop(key) == off, f"stage2={name}: stage2.{section}.{key} is not off"
    assert stage2 == GOLDEN["recipes"][name]
