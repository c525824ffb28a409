"""Issue 52 probes' pure helpers: the cue oracle's (cue_oracle.py) and the pair highlights' (pair_highlights.py)."""
import numpy as np
import pytest

from experiments.view_dependence.cue_oracle import nested_subsets, neighbourhood_mean


def test_neighbourhood_mean_averages_the_k_nearest_points_itself_included():
    xyz = np.array([[0.0, 0, 0], [1, 0, 0], [10, 0, 0], [11, 0, 0]])
    values = np.array([[1.0], [3.0], [10.0], [20.0]])
    # k=2: each point with its nearest neighbour, the two pairs kept apart
    np.testing.assert_allclose(neighbourhood_mean(xyz, values, 2)[:, 0], [2, 2, 15, 15])
    # k beyond n: every point gets the mean of all
    np.testing.assert_allclose(neighbourhood_mean(xyz, values, 99)[:, 0], np.full(4, 8.5))
    # k=1: the point itself
    np.testing.assert_allclose(neighbourhood_mean(xyz, values, 1), values)


def test_nested_subsets_grow_by_adding_scenes_and_are_seeded():
    names = [f"s{i:03d}" for i in range(40)]
    subsets = nested_subsets(names, [8, 16, 40], seed=0)
    assert [len(subsets[n]) for n in (8, 16, 40)] == [8, 16, 40]
    assert set(subsets[8]) <= set(subsets[16]) <= set(subsets[40]) == set(names)
    assert subsets == nested_subsets(names, [8, 16, 40], seed=0)
    assert subsets[8] != nested_subsets(names, [8], seed=1)[8]
    with pytest.raises(ValueError, match="asks for 41 training scenes, the folder has 40"):
        nested_subsets(names, [41], seed=0)


def test_highlight_summary_counts_the_points_above_the_gain():
    from experiments.view_dependence.pair_highlights import HIGHLIGHT_GAIN, highlight_summary

    gain = np.array([0.0, 0.01, 0.02, HIGHLIGHT_GAIN, 0.5, 3.0])  # the threshold itself is not a highlight
    out = highlight_summary(gain)
    assert out["share_highlit"] == pytest.approx(2 / 6)
    assert out["median"] == pytest.approx(np.median(gain))
    assert out["q90"] == pytest.approx(np.quantile(gain, 0.9))
