"""The study's Stage II options (experiments/training_pools/conf/stage2/) compose, with the study's
conf on gspi-train's search path, exactly as they did in conf/stage2 (golden_recipes.json)."""
import json
from pathlib import Path

import pytest

from tests.recipe_fixtures import composed_stage2

STUDY_CONF = Path(__file__).resolve().parents[1] / "conf"
GOLDEN = json.loads((Path(__file__).with_name("golden_recipes.json")).read_text())


@pytest.mark.parametrize("name", sorted(GOLDEN["recipes"]))
def test_the_study_recipe_composes_as_before(name):
    assert composed_stage2(f"stage2={name}", study_conf=STUDY_CONF) == GOLDEN["recipes"][name]


def test_a_retired_recipe_names_its_checkpoint_in_the_study():
    """The recipes of the retired checkpoints moved here with them (issue 67): a recipe that names a
    checkpoint (``checkpoint``, ``train.init_from``) names a file of this study's checkpoints/."""
    import yaml

    root = STUDY_CONF.parents[2]
    named = {}
    for path in sorted((STUDY_CONF / "stage2").glob("*.yaml")):
        node = yaml.safe_load(path.read_text()) or {}
        for value in (node.get("checkpoint"), (node.get("train") or {}).get("init_from")):
            if value:
                named[path.stem] = value
                assert value.startswith("experiments/training_pools/checkpoints/"), (path.name, value)
                assert (root / value).is_file(), (path.name, value)
    assert {"cpu_small", "cpu_pool224", "cpu_pool"} <= set(named)
