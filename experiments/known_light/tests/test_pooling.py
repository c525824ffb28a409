"""pooling.py's choice and table: the setting is chosen on the training rows only, ties keep the
shipped one, and the held-out difference is paired over scenes."""
from __future__ import annotations

import json

from experiments.known_light import pooling


def rows(avg_by_setting: dict[str, list[float]]) -> dict:
    n = len(next(iter(avg_by_setting.values())))
    return {f"s{i}": {"settings": {k: {"albedo": v[i], "roughness": v[i], "metallic": v[i], "avg": v[i]}
                                   for k, v in avg_by_setting.items()}} for i in range(n)}


def test_the_best_training_setting_wins_and_ties_keep_the_shipped_one():
    assert pooling.best_setting(rows({"k16_T0.1": [10, 12], "k64_T0.1": [11, 12]})) == "k64_T0.1"
    assert pooling.best_setting(rows({"k64_T0.1": [11, 12], "k16_T0.1": [11, 12]})) == "k16_T0.1"


def test_the_table_scores_the_training_choice_on_the_held_out_rows(tmp_path):
    train, held = tmp_path / "train.json", tmp_path / "held.json"
    train.write_text(json.dumps({"scenes": rows({"k16_T0.1": [10, 12], "k64_T0.1": [11, 13]})}))
    held.write_text(json.dumps({"scenes": rows({"k16_T0.1": [10, 12, 14], "k64_T0.1": [9, 11, 13]})}))
    text = pooling.table(train, held)
    assert "**k64_T0.1**" in text and "| k64_T0.1 (chosen) | 12.00 | 12.00 | 12.00 | 12.00 | 11.00 | 11.00 | 11.00 | 11.00 |" in text
    assert "avg -1.00 [-1.00, -1.00]" in text  # held out, the training choice loses 1 dB on every scene
