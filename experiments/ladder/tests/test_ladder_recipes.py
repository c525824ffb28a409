"""The ladder's Stage II options (experiments/ladder/conf/stage2/) compose, with the study's conf on
gspi-train's search path, exactly as they did in conf/stage2 (golden_recipes.json)."""
import json
from pathlib import Path

import pytest

from tests.recipe_fixtures import composed_stage2

STUDY_CONF = Path(__file__).resolve().parents[1] / "conf"
GOLDEN = json.loads((Path(__file__).with_name("golden_recipes.json")).read_text())


@pytest.mark.parametrize("name", sorted(GOLDEN["recipes"]))
def test_the_ladder_recipe_composes_as_before(name):
    assert composed_stage2(f"stage2={name}", study_conf=STUDY_CONF) == GOLDEN["recipes"][name]
