"""gspi/run/stage2_model.py and gspi/run/scene_digest.py: a trained Stage II model is cached by
what made it, the training scenes by content, so a moved or copied dataset reuses it (issue 54)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.stage2_fixtures import lattice_dataset, tiny_cfg  # noqa: F401 (the `dataset` fixture)


def run_cfg(dataset: Path, tmp_path: Path) -> dict:
    cfg = tiny_cfg(dataset, tmp_path / "unused")
    return {"stage2": {**cfg["stage2"], "checkpoint": None}, "data_dir": str(dataset), "seed": 0,
            "device": "cpu"}


def test_training_hash_follows_content_not_path(dataset, tmp_path):
    from gspi.run.stage2_model import training_hash

    cfg = run_cfg(dataset, tmp_path)
    copy = shutil.copytree(dataset, tmp_path / "elsewhere" / "renamed")
    assert training_hash({**cfg, "data_dir": str(copy)}) == training_hash(cfg)
    mask = copy / "train_0" / "train" / "005" / "mask.png"
    data = bytearray(mask.read_bytes())
    data[-20] ^= 0xFF  # one changed byte of one lattice view
    mask.write_bytes(bytes(data))
    assert training_hash({**cfg, "data_dir": str(copy)}) != training_hash(cfg)


def test_a_test_scene_does_not_enter_the_key(dataset, tmp_path):
    from gspi.run.stage2_model import training_hash

    cfg = run_cfg(dataset, tmp_path)
    copy = shutil.copytree(dataset, tmp_path / "c")
    (copy / "test_0" / "scene.json").write_text((copy / "test_0" / "scene.json").read_text() + " ")
    assert training_hash({**cfg, "data_dir": str(copy)}) == training_hash(cfg)


def test_a_copied_dataset_reuses_the_trained_model(dataset, tmp_path, monkeypatch):
    from gspi.run.stage2_model import load_or_train
    from gspi.stage2.config import complete_stage2

    cfg = run_cfg(dataset, tmp_path)
    stage2 = complete_stage2(cfg["stage2"])
    cache = tmp_path / "cache"
    _, _, first = load_or_train(cfg, stage2, cache)
    assert first["trained"]
    copy = shutil.copytree(dataset, tmp_path / "moved" / "data")
    calls = []
    monkeypatch.setattr("gspi.stage2.train.train", lambda *a, **k: calls.append(a))
    _, _, again = load_or_train({**cfg, "data_dir": str(copy)}, stage2, cache)
    assert calls == [] and not again["trained"] and again["checkpoint"] == first["checkpoint"]


def test_a_path_keyed_cache_is_adopted_not_retrained(dataset, tmp_path, monkeypatch):
    """A model trained before the content key (its folder named by the path-keyed hash) is kept."""
    from gspi.run.stage2_model import load_or_train, path_keyed_hash, training_hash
    from gspi.stage2.config import complete_stage2

    cfg = run_cfg(dataset, tmp_path)
    stage2 = complete_stage2(cfg["stage2"])
    cache = tmp_path / "cache"
    _, _, first = load_or_train(cfg, stage2, cache)
    new = Path(first["checkpoint"]).parent
    old = new.parent / path_keyed_hash(cfg)
    assert new.name == training_hash(cfg) != old.name
    new.rename(old)  # as an older version left it
    monkeypatch.setattr("gspi.stage2.train.train", lambda *a, **k: pytest.fail("retrained"))
    _, _, again = load_or_train(cfg, stage2, cache)
    assert again["checkpoint"] == first["checkpoint"] and not old.exists()
