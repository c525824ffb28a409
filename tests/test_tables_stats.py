"""eval.stats: mean ± SE against scipy; the paired percentile bootstrap vs scipy and theory."""
import math

import numpy as np
import pytest
import scipy.stats

from eval.stats import mean_and_sem, paired_bootstrap_ci, paired_differences


class TestMeanAndSem:
    def test_matches_scipy_sem(self):
        values = np.random.default_rng(0).normal(20.0, 3.0, size=11)
        mean, sem, n = mean_and_sem(values)
        assert n == 11
        assert mean == pytest.approx(float(np.mean(values)), rel=1e-12)
        assert sem == pytest.approx(float(scipy.stats.sem(values)), rel=1e-12)  # ddof=1

    def test_nan_is_a_missing_unit(self):
        mean, sem, n = mean_and_sem([1.0, float("nan"), 3.0])
        assert (mean, n) == (2.0, 2) and sem == pytest.approx(scipy.stats.sem([1.0, 3.0]))

    def test_one_unit_has_no_spread_and_none_has_no_mean(self):
        assert mean_and_sem([4.0])[0] == 4.0 and math.isnan(mean_and_sem([4.0])[1])
        mean, sem, n = mean_and_sem([float("nan")])
        assert math.isnan(mean) and math.isnan(sem) and n == 0

    def test_infinite_psnr_gives_infinite_mean_and_no_se(self):
        mean, sem, n = mean_and_sem([20.0, float("inf")])
        assert mean == float("inf") and math.isnan(sem) and n == 2


def _pairs(diffs, base=None):
    base = np.zeros(len(diffs)) if base is None else base
    ref = {("s%d" % i, 0): float(b) for i, b in enumerate(base)}
    var = {k: ref[k] + float(d) for k, d in zip(ref, diffs)}
    return var, ref


class TestPairedBootstrap:
    def test_constant_difference_gives_a_point_interval(self):
        var, ref = _pairs([-1.5] * 6, base=np.arange(6) * 10.0)  # scenes differ, pairs don't
        mean, lo, hi = paired_bootstrap_ci(var, ref, n_resamples=500)
        assert (mean, lo, hi) == pytest.approx((-1.5, -1.5, -1.5))

    def test_equals_scipy_percentile_bootstrap_with_the_same_generator(self):
        rng = np.random.default_rng(5)
        var, ref = _pairs(rng.normal(0.3, 1.0, 9), base=rng.normal(25, 4, 9))
        mean, lo, hi = paired_bootstrap_ci(var, ref, n_resamples=3000, seed=7)
        d = np.array([var[k] - ref[k] for k in sorted(var, key=repr)])
        res = scipy.stats.bootstrap((d,), np.mean, n_resamples=3000, method="percentile",
                                    rng=np.random.default_rng(7))
        assert mean == pytest.approx(d.mean())
        ci = res.confidence_interval
        assert (lo, hi) == pytest.approx((ci.low, ci.high))

    def test_pairs_only_keys_present_on_both_sides(self):
        var, ref = _pairs([1.0, 2.0, 3.0])
        var[("extra", 0)] = 100.0          # only in the variant
        ref[("other", 1)] = -100.0         # only in the reference
        var[("s0", 0)] = float("nan")      # a missing value drops its pair
        assert paired_differences(var, ref) == {("s1", 0): 2.0, ("s2", 0): 3.0}
        assert paired_bootstrap_ci(var, ref, n_resamples=100)[0] == pytest.approx(2.5)

    def test_deterministic_for_a_seed(self):
        var, ref = _pairs(np.random.default_rng(1).normal(size=8))
        a = paired_bootstrap_ci(var, ref, n_resamples=1000, seed=3)
        assert a == paired_bootstrap_ci(var, ref, n_resamples=1000, seed=3)
        assert a[1:] != paired_bootstrap_ci(var, ref, n_resamples=1000, seed=4)[1:]

    def test_covers_the_true_mean_difference(self):
        """Synthetic: 200 experiments of 30 paired units, true mean difference 1 dB."""
        rng = np.random.default_rng(0)
        hits = 0
        for trial in range(200):
            base = rng.normal(25, 5, 30)  # scene difficulty, shared by the pair
            var, ref = _pairs(rng.normal(1.0, 2.0, 30), base=base)
            _, lo, hi = paired_bootstrap_ci(var, ref, n_resamples=1000, seed=trial)
            hits += lo <= 1.0 <= hi
        assert 0.88 <= hits / 200 <= 0.99  # nominal 0.95; percentile is slightly liberal

    def test_width_matches_the_normal_interval_for_many_units(self):
        d = np.random.default_rng(2).normal(0.0, 1.0, 400)
        var, ref = _pairs(d)
        mean, lo, hi = paired_bootstrap_ci(var, ref, n_resamples=4000)
        half = 1.959964 * scipy.stats.sem(d)
        assert (hi - lo) / 2 == pytest.approx(half, rel=0.1)
        assert lo < mean < hi

    def test_refuses_fewer_than_two_pairs(self):
        var, ref = _pairs([1.0])
        with pytest.raises(ValueError, match="at least 2 units"):
            paired_bootstrap_ci(var, ref)
        with pytest.raises(ValueError, match="confidence"):
            paired_bootstrap_ci(*_pairs([1.0, 2.0]), confidence=95)
