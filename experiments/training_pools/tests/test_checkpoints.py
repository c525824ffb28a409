"""The study's retired Stage II checkpoints (experiments/training_pools/checkpoints/, moved from the
product's checkpoints/ by issue 67): every card names its file and that file's SHA-256, every .pt
has a card, each pool model is what its recipe here trains, no stored config names a machine path,
and the product's rule record of each retired candidate is what its card records."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

STUDY = Path(__file__).resolve().parents[1]
ROOT = STUDY.parents[1]
CHECKPOINTS = STUDY / "checkpoints"
CARDS = sorted(CHECKPOINTS.glob("stage2_*.json"))
XS_PARAMETERS = 349141  # Table 2's XS model with the 35-dim local condition
PIXEL_PARAMETERS = XS_PARAMETERS + 256 * 48  # + 256 pixel-feature inputs x the point stream width


def test_the_retired_checkpoints_are_here():
    assert {c.stem for c in CARDS} >= {"stage2_small", "stage2_pool224_pixel", "stage2_parts_pool"}


@pytest.mark.parametrize("card", CARDS, ids=lambda p: p.name)
def test_card_names_its_file_and_hash(card):
    data = json.loads(card.read_text())
    path = ROOT / data["file"]
    assert path.is_file() and path.parent == CHECKPOINTS, card
    assert path.stem == card.stem, f"{card.name} describes {data['file']}"
    assert hashlib.sha256(path.read_bytes()).hexdigest() == data["sha256"], card.name
    assert path.stat().st_size == data["size_bytes"]
    assert data["status"] == "retired"


def test_every_checkpoint_has_a_card():
    for pt in sorted(CHECKPOINTS.glob("stage2_*.pt")):
        assert pt.with_suffix(".json").is_file(), f"{pt.name} has no card"


@pytest.mark.parametrize("name, preset, steps, parameters", [
    ("stage2_pool_trunc_snr", "cpu_pool_trunc_snr", 2500, XS_PARAMETERS),
    ("stage2_pool_recon", "cpu_pool_recon", 2500, XS_PARAMETERS),
    ("stage2_pool224", "cpu_pool224", 2500, XS_PARAMETERS),
    ("stage2_pool224_5k", "cpu_pool224_5k", 5000, XS_PARAMETERS),
    ("stage2_pool224_pixel", "cpu_pool224_pixel", 2500, PIXEL_PARAMETERS)])
def test_the_pool_checkpoints_are_their_recipes(name, preset, steps, parameters):
    """<name>.pt loads, is under 20 MB, is what the study's conf/stage2/<preset>.yaml trains (the
    truncated-SNR weight, the recipe's steps and sizes) and is the file its card hashes."""
    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR
    from gspi.stage2.checkpoint import load_stage2_checkpoint

    path = CHECKPOINTS / f"{name}.pt"
    assert path.stat().st_size < 20e6
    card = json.loads(path.with_suffix(".json").read_text())
    model, cfg = load_stage2_checkpoint(path)
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        recipe = compose("gspi_train", overrides=[f"hydra.searchpath=[file://{STUDY / 'conf'}]",
                                                  f"stage2={preset}", "data_dir=d", "out=o"])
    assert recipe.stage2.checkpoint == str(path.relative_to(ROOT))
    stage2 = cfg["stage2"]
    assert stage2.diffusion.min_snr_floor == 1.0 and stage2.diffusion.prediction == "x0"
    assert stage2.train.steps == recipe.stage2.train.steps == steps
    assert stage2.model == {k: recipe.stage2.model[k] for k in stage2.model}
    assert stage2.data.pixel_features == recipe.stage2.data.pixel_features == (parameters != XS_PARAMETERS)
    assert not model.training and sum(p.numel() for p in model.parameters()) == card["parameters"] == parameters


def _stored_strings(value):
    if isinstance(value, dict):
        for item in value.values():
            yield from _stored_strings(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from _stored_strings(item)
    elif isinstance(value, str):
        yield value


@pytest.mark.parametrize("pt", sorted(CHECKPOINTS.glob("stage2_*.pt")), ids=lambda p: p.name)
def test_no_checkpoint_names_a_machine_path(pt):
    from gspi.stage2.checkpoint import read_checkpoint
    from tests.machine_paths import MACHINE_PATH

    found = [s for s in _stored_strings(read_checkpoint(pt)["config"]) if MACHINE_PATH.search(s)]
    assert not found, f"{pt.name}: {found}"


def test_the_products_rule_records_are_what_the_cards_record():
    """make results reads the retired candidates' shipping-rule scores from the product's store
    (results/shipping/cpu/<model>/scores.json): one per card here that records end-to-end runs,
    reading to the same scores."""
    from eval.tables.cards import read_card

    records = {p.parent.name: read_card(p) for p in sorted((ROOT / "results" / "shipping" / "cpu").glob("*/scores.json"))}
    cards = {c.stem: read_card(c) for c in CARDS}
    assert records == {name: scores for name, scores in cards.items() if scores is not None}
