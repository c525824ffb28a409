"""Uncertainty of table cells: mean ± standard error and the paired bootstrap of a difference.

The unit of every statistic here is one (scene, seed) pair: a run of a variant with one seed,
scored on one scene (the per-scene mean over that scene's views, docs/TABLES.md). Pure
functions, no I/O.
"""
from __future__ import annotations

import math
from collections.abc import Hashable, Iterable, Mapping

import numpy as np

MIN_PAIRS = 2


def mean_and_sem(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean and standard error of the mean of per-unit values.

    SE = sample standard deviation (n - 1 denominator) / sqrt(n), the usual estimate of the
    spread of the mean over repeated draws of units (= scipy.stats.sem with ddof=1).

    NaN rules: NaN values are missing units and are dropped before anything is computed; `n`
    counts the remaining values. n = 0 gives (nan, nan, 0); n = 1 gives (value, nan, 1), since
    one unit says nothing about spread. An infinite value (a PSNR of identical images) makes
    the mean that infinity (or nan for +inf and -inf together) and the SE nan.

    Args:
        values: per-unit values in the table's display units (dB, %, minutes).

    Returns:
        (mean, sem, n).
    """
    arr = np.asarray(list(values), dtype=np.float64).reshape(-1)
    arr = arr[~np.isnan(arr)]
    n = int(arr.size)
    if n == 0:
        return math.nan, math.nan, 0
    if not np.isfinite(arr).all():
        with np.errstate(invalid="ignore"):
            return float(arr.mean()), math.nan, n
    if n == 1:
        return float(arr[0]), math.nan, 1
    return float(arr.mean()), float(arr.std(ddof=1) / math.sqrt(n)), n


def paired_differences(variant: Mapping[Hashable, float], reference: Mapping[Hashable, float]
                       ) -> dict[Hashable, float]:
    """`variant[k] - reference[k]` for the keys present in both with finite values on both sides.

    Keys are the paired units, (scene, seed) in the tables: a unit scored for one side only, or
    with an infinite/NaN value on either side, has no defined difference and is left out.
    """
    out = {}
    for key in variant.keys() & reference.keys():
        v, r = float(variant[key]), float(reference[key])
        if math.isfinite(v) and math.isfinite(r):
            out[key] = v - r
    return out


def paired_bootstrap_ci(variant: Mapping[Hashable, float], reference: Mapping[Hashable, float],
                        *, n_resamples: int = 10000, confidence: float = 0.95, seed: int = 0
                        ) -> tuple[float, float, float]:
    """Mean paired difference `variant - reference` and its percentile bootstrap interval.

    Pairing: the units are the keys present in both mappings (with finite values on both
    sides, see `paired_differences`), so scene difficulty and seed cancel within a pair. The
    n paired differences d_1..d_n are resampled with replacement (n draws, `n_resamples`
    times, numpy `Generator` from `seed`); the interval is the (1 - confidence)/2 and
    (1 + confidence)/2 percentiles (linear interpolation) of the resampled means.

    Why percentile: it assumes no normal shape of the mean's distribution (with 4-20 units
    it is often skewed), it returns values the mean can take ([d, d] for a constant
    difference), and with this few units the bias and acceleration estimates of BCa are
    themselves noisy (BCa is undefined for a constant difference). It is the interval
    scipy.stats.bootstrap(method="percentile") computes; it is written out here because
    that function's `rng=` argument needs scipy >= 1.15 and the draws must be reproducible
    from `seed` alone (tests check both agree exactly).

    Args:
        variant, reference: {unit key: value}, e.g. {(scene, seed): PSNR in dB}.
        n_resamples: bootstrap resamples (10000 keeps the Monte-Carlo error of a 95 %
            bound well below the SE for any n).
        confidence: interval coverage in (0, 1).
        seed: seed of numpy's default Generator (PCG64).

    Returns:
        (mean difference, lower bound, upper bound), in the units of the inputs.

    Raises:
        ValueError: fewer than 2 pairs (no spread can be estimated), bad n_resamples or
            confidence.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if int(n_resamples) < 1:
        raise ValueError(f"n_resamples must be >= 1, got {n_resamples}")
    diffs = paired_differences(variant, reference)
    if len(diffs) < MIN_PAIRS:
        raise ValueError(f"paired bootstrap needs at least {MIN_PAIRS} units scored for both "
                         f"the variant and the reference with finite values; got {len(diffs)} "
                         f"(variant units: {len(variant)}, reference units: {len(reference)})")
    d = np.array([diffs[k] for k in sorted(diffs, key=repr)], dtype=np.float64)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, d.size, (int(n_resamples), d.size))
    means = d[idx].mean(axis=-1)
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.percentile(means, [100.0 * alpha, 100.0 * (1.0 - alpha)])
    return float(d.mean()), float(lo), float(hi)
