"""eval/tables/cards.py: the three layouts of a checkpoint card's end-to-end scores read alike,
the shipping rule computed from them, and each card's status (default | table | retired) as the
configs give it."""
import json
from pathlib import Path

import pytest

from eval.tables.cards import (cards_with_status, configured_statuses, read_card, read_status, rule_failures,
                               with_status)

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


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_a_rule_record_reads_back_to_its_card(tmp_path, layout):
    """A retired card leaves with its file (issue 67); its rule record (results/shipping/cpu/) reads
    back to the same scores, under the model's name rather than the file's."""
    from eval.tables.cards import rule_record

    card = read_card(_card(tmp_path, LAYOUTS[layout]))
    (tmp_path / "stage2_x").mkdir()
    record = tmp_path / "stage2_x" / "scores.json"
    record.write_text(json.dumps(rule_record(card)))
    assert read_card(record) == card and rule_record(read_card(record)) == rule_record(card)


def test_the_committed_rule_records_are_rule_candidates():
    root = Path(__file__).resolve().parents[1]
    records = sorted((root / "results" / "shipping" / "cpu").glob("*/scores.json"))
    assert records and all(read_card(p).model == p.parent.name for p in records)
    assert not {p.parent.name for p in records} & {c.stem for c in (root / "checkpoints").glob("stage2_*.json")}


def test_a_card_without_end_to_end_runs_is_no_candidate(tmp_path):
    assert read_card(_card(tmp_path, {})) is None


# ---- status: default | table | retired, from the configs (eval.tables.cards.configured_statuses)

def _fake_repo(tmp_path, cards=("stage2_a", "stage2_b", "stage2_c"), default="stage2_a", tables=("stage2_b",)):
    (tmp_path / "conf" / "stage2").mkdir(parents=True)
    (tmp_path / "conf" / "reproduce").mkdir()
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "conf" / "gspi_run.yaml").write_text("defaults:\n  - _self_\n  - stage2: shipped\n")
    (tmp_path / "conf" / "stage2" / "shipped.yaml").write_text(f"checkpoint: checkpoints/{default}.pt\n")
    entries = "".join(f"  full_s{i}: checkpoints/{name}.pt\n" for i, name in enumerate(tables))
    (tmp_path / "conf" / "reproduce" / "table2_cpu.yaml").write_text(f"checkpoints_from:\n{entries}")
    (tmp_path / "conf" / "reproduce" / "table2_smoke.yaml").write_text("checkpoints_from: null\n")
    for name in cards:
        (tmp_path / "checkpoints" / f"{name}.json").write_text(json.dumps({"file": f"checkpoints/{name}.pt", "sha256": "x"}))
    return tmp_path


def test_statuses_follow_the_configs(tmp_path):
    root = _fake_repo(tmp_path)
    assert configured_statuses(root) == {"stage2_a": "default", "stage2_b": "table", "stage2_c": "retired"}
    # the default wins over a table that measures it too (Table 2's Full s0 is the shipped default)
    root2 = _fake_repo(tmp_path / "two", tables=("stage2_a", "stage2_b"))
    assert configured_statuses(root2)["stage2_a"] == "default"


def test_written_cards_carry_their_status_after_file(tmp_path):
    root = _fake_repo(tmp_path)
    texts = cards_with_status(root)
    for path, text in texts.items():
        path.write_text(text)
    card = json.loads((root / "checkpoints" / "stage2_b.json").read_text())
    assert list(card) == ["file", "status", "sha256"] and card["status"] == "table"
    assert read_status(root / "checkpoints" / "stage2_c.json") == "retired"
    assert cards_with_status(root) == texts  # written once, nothing left to change


def test_a_missing_status_or_default_card_is_named(tmp_path):
    root = _fake_repo(tmp_path)
    with pytest.raises(ValueError, match=r"stage2_a.json: status None"):
        read_status(root / "checkpoints" / "stage2_a.json")
    with pytest.raises(ValueError, match="status 'gone'"):
        with_status({"file": "x"}, "gone")
    (root / "checkpoints" / "stage2_a.json").unlink()
    with pytest.raises(ValueError, match="stage2_a has no card"):
        configured_statuses(root)


def test_the_committed_cards_status_matches_the_configs():
    """Exactly one card is the default, the checkpoint conf/gspi_run.yaml's stage2 option names;
    every card's status is what the configs give it (`make results` writes them)."""
    import yaml

    root = Path(__file__).resolve().parents[1]
    cards = sorted((root / "checkpoints").glob("stage2_*.json"))
    statuses = {card.stem: read_status(card) for card in cards}
    assert statuses == configured_statuses(root), "run `make results` (eval.tables.cards writes the statuses)"
    defaults = yaml.safe_load((root / "conf" / "gspi_run.yaml").read_text())["defaults"]
    option = next(d["stage2"] for d in defaults if isinstance(d, dict) and "stage2" in d)
    named = yaml.safe_load((root / "conf" / "stage2" / f"{option}.yaml").read_text())["checkpoint"]
    assert [stem for stem, status in statuses.items() if status == "default"] == [Path(named).stem]
    described = [card.stem for card in cards if "default" in json.loads(card.read_text())]
    assert described == [Path(named).stem]  # the card that says why it is the default is the default


def test_every_shipped_card_names_the_command_that_rebuilds_it(tmp_path, capsys):
    """A card the product ships (default or table) carries ``rebuild``: a gspi-reproduce call whose
    dry run plans the training of the card's recipe (not a measure of the committed file)."""
    import shlex

    from gspi.cli import reproduce as cli

    root = Path(__file__).resolve().parents[1]
    shipped = {c: json.loads(c.read_text()) for c in sorted((root / "checkpoints").glob("stage2_*.json"))}
    shipped = {c: card for c, card in shipped.items() if card["status"] in ("default", "table")}
    assert shipped
    for path, card in shipped.items():
        command = shlex.split(card.get("rebuild", ""))
        assert command[:1] == ["gspi-reproduce"], f"{path.name}: no rebuild command (make results writes it)"
        assert cli.main([*command[1:], f"data_root={tmp_path}", "dry_run=true"]) == 0
        out = capsys.readouterr().out
        recipe = Path(card["file"]).stem.removeprefix("stage2_")
        trains = [line for line in out.splitlines() if line.startswith("train: ")]
        assert trains and all(f"stage2=cpu_{recipe}" in line for line in trains), out
        assert not any("checkpoints/" in line for line in out.splitlines() if line.startswith("measure: "))


def test_a_model_reproduce_file_rebuilds_the_default_only(tmp_path):
    from eval.tables.cards import configured_rebuilds

    root = _fake_repo(tmp_path)
    assert configured_rebuilds(root) == {}
    (root / "conf" / "reproduce" / "model_default_cpu.yaml").write_text("model: default\n")
    assert configured_rebuilds(root) == {"stage2_a": "gspi-reproduce model=default scale=cpu"}
    texts = cards_with_status(root)
    assert list(json.loads(texts[root / "checkpoints" / "stage2_a.json"])) == ["file", "status", "rebuild", "sha256"]
    (root / "conf" / "reproduce" / "model_other_cpu.yaml").write_text("model: other\n")
    with pytest.raises(ValueError, match="model_other_cpu.yaml: model 'other'"):
        configured_rebuilds(root)
