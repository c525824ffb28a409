"""Stage II recipes (conf/stage2/*.yaml): flat files whose composition never changed.

tests/golden/stage2_recipes.json holds every recipe and ablation as gspi-train composed it before
issue 53 flattened the chains; a flattened file must compose to exactly the same values.
"""
import json
from pathlib import Path

import pytest
import yaml

from tests.recipe_fixtures import composed_stage2

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
GOLDEN = json.loads((ROOT / "tests" / "golden" / "stage2_recipes.json").read_text())
FLAT = ["cpu_pool224_pixel_5k",  # the shipped default's recipe (checkpoints/README.md), rewritten flat by issue 53
        "table2_cpu",            # Table 2's CPU recipe, flat since issue 53
        "cpu_capacity"]          # the capacity curve's, flat since issue 67 retired the recipe it inherited


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
