"""eval/tables/cards.py: the three layouts of a checkpoint card's end-to-end scores read alike,
and the shipping rule computed from them."""
import json

import pytest

from eval.tables.cards import read_card, rule_failures

REAL0 = {"albedo": 12.0, "roughness": 11.0, "metallic": 20.0, "relight": 16.0}
REAL1 = {"albedo": 13.0, "roughness": 12.0, "metallic": 21.0, "relight": 17.0}
BASE = {"albedo": 11.5, "roughness": 9.76, "metallic": 9.26, "relight": 17.15}
HELD = {"heldout_pool_scenes_reconstructed_conditions": {"psnr_mean_of_2_seeds": {"avg": 14.5}}}
LAYOUTS = {
    "lists": {"demo_end_to_end": {"s004": {"metal_iou": [0.9, 0.8], "metallic_psnr": [15.0, 14.0]}},
              "real_objects_19_small": {"mean_psnr_seed0": REAL0, "mean_psnr_seed1": REAL1,
                                        "no_decomposition_same_data": BASE}},
    "suffixed": {"demo_end_to_end": {"s004_seed0": {"metal_iou": 0.9, "metallic_psnr": 15.0},
                                     "s004_seed1": {"metal_iou": 0.8, "metallic_psnr": 14.0}},
                 "real_objects_19_small": {"mean_psnr_seed0": REAL0, "mean_psnr_seed1": REAL1,
                                           "no_decomposition_same_data": BASE}},
    "nested": {"demo_end_to_end": {"seed0": {"s004": {"metal_iou": 0.9, "metallic_psnr": 15.0}},
                                   "seed1": {"s004": {"metal_iou": 0.8, "metallic_psnr": 14.0}}},
               "real_objects_19_small": {"seed0": {"mean_psnr": REAL0}, "seed1": {"mean_psnr": REAL1},
                                         "no_decomposition_same_data": BASE}},
}


def _card(tmp_path, body, name="stage2_x"):
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps({**HELD, **body}))
    return path


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_reads_to_the_same_record(tmp_path, layout):
    card = read_card(_card(tmp_path, LAYOUTS[layout]))
    assert (card.model, card.heldout_avg, card.heldout_seeds) == ("stage2_x", 14.5, 2)
    assert card.s004_iou == [0.9, 0.8] and card.s004_metallic == [15.0, 14.0]
    assert card.real == [REAL0, REAL1] and card.real_baseline == BASE
    assert rule_failures(card) == []  # metal found; behind only on relight, which the rule ignores


def test_the_rule_names_what_fails(tmp_path):
    body = json.loads(json.dumps(LAYOUTS["nested"]))
    body["demo_end_to_end"]["seed0"]["s004"]["metal_iou"] = 0.1
    body["real_objects_19_small"]["seed0"]["mean_psnr"]["roughness"] = 9.0
    assert rule_failures(read_card(_card(tmp_path, body))) == ["s004", "roughness"]


def test_a_card_without_end_to_end_runs_is_no_candidate(tmp_path):
    assert read_card(_card(tmp_path, {})) is None
