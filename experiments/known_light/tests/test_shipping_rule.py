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
