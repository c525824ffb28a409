"""experiments.asset_radiance.highlights: radiance statistics inside a mask, computed by hand."""
from __future__ import annotations

import numpy as np
import pytest

from experiments.asset_radiance.highlights import radiance_stats


def test_radiance_stats_by_hand():
    images = np.zeros((1, 2, 2, 3), np.float32)
    images[0, 0, 0] = [2.0, 0.5, 0.5]      # a highlight: one channel above 1
    images[0, 0, 1] = [0.5, 0.5, 0.5]
    images[0, 1, 1] = [9.0, 9.0, 9.0]      # outside the mask: ignored
    mask = np.array([[[True, True], [True, False]]])
    s = radiance_stats(images, mask)
    assert s["mean"] == pytest.approx((2.0 + 0.5 * 5) / 9)
    assert s["max"] == 2.0 and s["frac_above_1"] == pytest.approx(1 / 3) and s["q50"] == 0.5
    # encoder input: clamp to [0, 1], sRGB: 1 -> 1, 0.5 -> 0.7354, 0 -> 0
    assert s["encoder_mean"] == pytest.approx((1.0 + 0.735357 * 5) / 9, abs=1e-5)
