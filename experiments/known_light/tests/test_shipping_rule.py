"""Issue 66's revised shipping rule as shipping_rule.py applies it, on the default's own scores moved
by known amounts: each failing clause is named, and a candidate clear on every clause passes."""
from __future__ import annotations

from experiments.known_light import shipping_rule as rule


def shifted(**delta: float) -> dict[int, dict]:
    full = rule.full_scores(0)
    return {0: {s: {c: v + delta.get(c, 0.0) for c, v in row.items()} for s, row in full.items()}}


def test_the_default_against_itself_is_level_and_fails_the_average():
    d, lo, hi = rule.paired(shifted(), "avg")
    assert (d, lo, hi) == (0.0, 0.0, 0.0)
    assert "no: avg CI not above 0" in rule.rule_row("itself", shifted(), None)


def test_a_channel_loss_beyond_half_a_db_is_named():
    row = rule.rule_row("worse roughness", shifted(albedo=2.0, metallic=2.0, roughness=-0.6), "light_fit_recon_fast_18")
    assert row.endswith("| no: roughness CI lower bound -0.60 < -0.5 |")


def test_a_candidate_clear_on_every_clause_passes():
    row = rule.rule_row("better", shifted(albedo=1.0, roughness=-0.4, metallic=1.0), "light_fit_recon_fast_18")
    assert "| +0.53 [+0.53, +0.53] |" in row and row.endswith("| 100% of 9 | 100% of 9 | yes (then issue 42's checks) |")


def test_the_guard_rail_counts_the_scenes_told_a_wrong_light(tmp_path):
    """A scene counts only when the light told differs from its estimate as the measure says."""
    import json

    from experiments.known_light.shipping_rule import told_wrong

    est = {"env": "sunset", "rotation_deg": 10.0}
    lights = {"a": {**est, "told": {"how": "other", "env": "overcast", "rotation_deg": 10.0}},
              "b": {**est, "told": {"how": "other", "env": "sunset", "rotation_deg": 10.0}},  # not wrong
              "c": est}
    path = tmp_path / "scores.json"
    path.write_text(json.dumps({"lights": lights}))
    assert told_wrong([path, tmp_path / "absent.json"], "other") == "1 of 3"
    assert told_wrong([path], "turned90") == "0 of 3"
    assert told_wrong([path], "estimated") == "none"


def test_a_study_pairs_record_is_read_before_the_products_and_one_in_neither_is_not_measured(tmp_path, monkeypatch):
    import json

    pairs = {"roughness": {"pairs": 3, "ordered_with_gap": 2 / 3}, "metal": {"pairs": 3, "separated": 1.0}}
    (tmp_path / "both.json").write_text(json.dumps(pairs))
    monkeypatch.setattr(rule, "STUDY_PAIRS", tmp_path / "{run}.json")
    assert rule.pairs_record("both") == tmp_path / "both.json"
    assert rule.pairs_record("light_fit_recon_fast_18") == rule.ROOT / "results/controlled_pairs/cpu/light_fit_recon_fast_18.json"
    assert rule.pairs_record("absent") is None and rule.pairs_record(None) is None
    assert rule.pairs_cells("both") == ("67% of 3", "100% of 3", ["ordered < 90 %"])
    assert rule.pairs_cells("absent")[2] == ["controlled pairs not measured"]
