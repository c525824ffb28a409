"""benchmarks/bench_stage2_train.py: its settings grammar and one tiny timing of each kind
(figures are never asserted: speed lives in benchmarks, not tests)."""
import math

import pytest

from benchmarks.bench_stage2_train import label, parse_setting, time_ddp, time_setting


@pytest.mark.parametrize("text, parsed", [("1x8", (1, 1, 8)), ("2x32", (1, 2, 32)), ("2px1x32", (2, 1, 32))])
def test_settings_grammar(text, parsed):
    assert parse_setting(text) == parsed


def test_one_process_and_two_gloo_processes_both_time_a_step():
    one = time_setting(1, 2, repeats=1, compile_model=False)
    two = time_ddp(2, 1, 2, repeats=1)
    for r in (one, two):
        assert r["s_per_step"] > 0 and math.isclose(r["points_per_s"], 2 * 512 / r["s_per_step"])
    assert label(one) == "1x2" and label(two) == "2px1x2"
