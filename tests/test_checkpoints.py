"""The shipped Stage II checkpoints (checkpoints/README.md): every card names its file and that
file's SHA-256, every .pt has a card, and gspi-run's default model loads with the config its
card and its recipe name (issue 42)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CARDS = sorted((ROOT / "checkpoints").glob("stage2_*.json"))


def default_stage2() -> str:
    """The stage2 group option gspi-run's defaults list chooses."""
    defaults = yaml.safe_load((ROOT / "conf" / "gspi_run.yaml").read_text())["defaults"]
    return next(d["stage2"] for d in defaults if isinstance(d, dict) and "stage2" in d)


@pytest.mark.parametrize("card", CARDS, ids=lambda p: p.name)
def test_card_names_its_file_and_hash(card):
    data = json.loads(card.read_text())
    path = ROOT / data["file"]
    assert path.is_file(), card
    assert path.stem == card.stem, f"{card.name} describes {data['file']}"
    assert hashlib.sha256(path.read_bytes()).hexdigest() == data["sha256"], card.name
    assert path.stat().st_size == data["size_bytes"]


def test_every_checkpoint_has_a_card_and_a_readme_row():
    readme = (ROOT / "checkpoints" / "README.md").read_text()
    for pt in sorted((ROOT / "checkpoints").glob("stage2_*.pt")):
        assert pt.with_suffix(".json").is_file(), f"{pt.name} has no card"
        assert f"`{pt.name}`" in readme, f"{pt.name} is not listed in checkpoints/README.md"


def test_the_default_model_loads_and_is_the_one_the_readme_names():
    from gspi.stage2.checkpoint import load_stage2_checkpoint

    option = default_stage2()
    node = yaml.safe_load((ROOT / "conf" / "stage2" / f"{option}.yaml").read_text())
    ckpt = ROOT / node["checkpoint"]
    model, saved = load_stage2_checkpoint(ckpt)
    assert sum(p.numel() for p in model.parameters()) > 0 and saved["stage2"].model is not None
    readme = (ROOT / "checkpoints" / "README.md").read_text()
    default_line = next(line for line in readme.splitlines() if line.startswith("**Default"))
    assert f"`{ckpt.name}`" in default_line and f"stage2={option}" in default_line, default_line


def test_exactly_one_card_says_it_is_the_default_and_it_is_gspi_runs():
    """A former default keeps its history under `was_default`; only today's card has `default`."""
    claiming = [card.name for card in CARDS if "default" in json.loads(card.read_text())]
    node = yaml.safe_load((ROOT / "conf" / "stage2" / f"{default_stage2()}.yaml").read_text())
    assert claiming == [Path(node["checkpoint"]).with_suffix(".json").name]


def stored_strings(value):
    """Every string inside a checkpoint's stored config (dicts, lists, tuples)."""
    if isinstance(value, dict):
        for item in value.values():
            yield from stored_strings(item)
    elif isinstance(value, (list, tuple)):
        for item in value:
            yield from stored_strings(item)
    elif isinstance(value, str):
        yield value


@pytest.mark.parametrize("pt", sorted((ROOT / "checkpoints").glob("stage2_*.pt")), ids=lambda p: p.name)
def test_no_shipped_checkpoint_names_a_machine_path(pt):
    """A shipped file is tracked too (issue 53): its stored config names no machine's folders."""
    from gspi.stage2.checkpoint import read_checkpoint
    from tests.machine_paths import MACHINE_PATH

    found = [s for s in stored_strings(read_checkpoint(pt)["config"]) if MACHINE_PATH.search(s)]
    assert not found, f"{pt.name}: {found}"


def test_the_export_makes_the_config_portable_and_keeps_the_weights(tmp_path):
    import torch

    from gspi.stage2.checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, ema_only, make_portable, save_atomic

    elsewhere = "/" + "/".join(("work", "pool", "rpool224"))  # built: this file itself names no machine path
    ckpt = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "step": 5, "rcw_config": {},
            "config": {"data_dir": elsewhere, "out": str(ROOT / "runs" / "x_s0"), "seed": 0,
                       "stage2": {"train": {"init_from": "checkpoints/stage2_pool224_pixel_5k.pt"}}},
            "ema": {"w": torch.arange(4.0)}, "model": {}, "optimizer": {}}
    shipped = ema_only(ckpt)
    assert shipped["config"] == {"data_dir": "<elsewhere>/pool/rpool224", "out": "runs/x_s0", "seed": 0,
                                 "stage2": {"train": {"init_from": "checkpoints/stage2_pool224_pixel_5k.pt"}}}
    assert torch.equal(shipped["ema"]["w"], torch.arange(4.0)) and "optimizer" not in shipped
    path = save_atomic(ckpt, tmp_path / "c.pt")
    assert make_portable(path) and not make_portable(path)  # the second call finds nothing to rewrite
    again = torch.load(path, weights_only=True)
    assert again["config"]["data_dir"] == "<elsewhere>/pool/rpool224" and torch.equal(again["ema"]["w"], ckpt["ema"]["w"])
