"""Table 2's measure as a protocol (eval/points_protocol.py, conf/points_measure/): one hash, by
Table 1's hasher, that is stable, changes with any knob, and that scores written before it was
recorded reproduce."""
import json
from pathlib import Path

import pytest
import yaml

from eval.points_protocol import (ADDED_KNOBS, MEASURE_DEFAULTS, MeasureError, measure_hash, measure_knobs, measure_record,
                                  recorded_measure_hash)
from eval.protocol_id import HASH_CHARS, protocol_hash

ROOT = Path(__file__).resolve().parents[1]
TABLE2 = yaml.safe_load((ROOT / "conf" / "points_measure" / "table2.yaml").read_text())
OTHER = {"split": "val", "num_steps": 11, "max_points": 20001, "seed": 1, "num_samples": 2,
         "guidance_scale": 1.5, "patch_points": 512, "patch_coverage": 3.0, "told_light": "turned90"}


def test_table2_is_the_measure_the_committed_scores_were_taken_with():
    assert {k: TABLE2[k] for k in ("num_steps", "max_points", "seed")} == {"num_steps": 10, "max_points": 20000,
                                                                          "seed": 0}
    assert set(TABLE2) == {"name", *MEASURE_DEFAULTS}  # every knob stated
    committed = sorted((ROOT / "results" / "table2" / "cpu").glob("*/scores.json"))
    assert committed and {recorded_measure_hash(json.loads(p.read_text())) for p in committed} == {measure_hash(TABLE2)}


def test_the_hash_is_table1s_hasher_stable_and_blind_to_spelling_and_name():
    h = measure_hash(TABLE2)
    knobs = {k: v for k, v in measure_knobs(TABLE2).items() if k not in ADDED_KNOBS}  # at their defaults here
    assert len(h) == HASH_CHARS and h == protocol_hash(knobs) == measure_hash(dict(TABLE2))
    assert h == "a43f7578f7d9"  # pinned: a change here splits every committed Table 2 from new measures
    assert measure_hash({**TABLE2, "name": "renamed", "guidance_scale": 1, "num_steps": 10.0}) == h
    assert measure_record("table2", TABLE2) == {"name": "table2", "hash": h}


@pytest.mark.parametrize("key", sorted(OTHER))
def test_the_hash_changes_with_any_knob(key):
    assert OTHER[key] != TABLE2[key]
    assert measure_hash({**TABLE2, key: OTHER[key]}) != measure_hash(TABLE2)


def test_an_unknown_key_or_a_bad_value_is_refused():
    with pytest.raises(MeasureError, match="unknown key.*num_step\\b"):
        measure_knobs({**TABLE2, "num_step": 5})
    with pytest.raises(MeasureError, match="points_measure.num_steps='ten'"):
        measure_knobs({**TABLE2, "num_steps": "ten"})
    with pytest.raises(MeasureError, match="points_measure.seed: null"):
        measure_knobs({**TABLE2, "seed": None})
    with pytest.raises(MeasureError, match="told_light='rotated'.*estimated, turned90, other"):
        measure_knobs({**TABLE2, "told_light": "rotated"})


def test_a_knob_added_later_keeps_every_earlier_hash_at_its_default():
    """told_light came after the committed scores: absent or at its default, the hash is the pinned
    one; set off it, another measure (and the two wrong lights are two measures)."""
    before = {k: v for k, v in TABLE2.items() if k != "told_light"}
    assert measure_hash(before) == measure_hash(TABLE2) == "a43f7578f7d9"
    assert len({measure_hash({**TABLE2, "told_light": t}) for t in ("estimated", "turned90", "other")}) == 3


def test_a_recorded_hash_is_read_and_an_absent_one_computed_from_the_knobs():
    old = {"split": "test", "num_steps": 10, "max_points": 20000, "seed": 0}  # before measure_protocol
    assert recorded_measure_hash(old) == measure_hash(TABLE2)
    assert recorded_measure_hash({**old, "num_samples": 4}) != measure_hash(TABLE2)
    assert recorded_measure_hash({**old, "measure_protocol": {"name": "x", "hash": "0123"}}) == "0123"
