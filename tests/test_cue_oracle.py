"""The cue oracle's two pure helpers (experiments/view_dependence/cue_oracle.py, issue 52)."""
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
