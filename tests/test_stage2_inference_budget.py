"""stage2.inference.points_per_gaussian and light_fit's method.points_per_gaussian: the points read
sized to the asset (issue 68)."""
import pytest

from gspi.stage2.infer import InferenceConfig, subsample_indices
from gspi.stage2.light_fit import LightFitConfig


@pytest.mark.parametrize("max_points, ppg, gaussians, expected", [
    (None, None, 2933, None),      # the paper: the whole cloud
    (20000, None, 2933, 20000),    # no asset budget: max_points as set
    (20000, 2.0, 2933, 5866),      # the asset's budget under max_points
    (20000, 2.0, 50000, 20000),    # max_points still caps a large asset
    (None, 1.5, 1001, 1502),       # rounded; no max_points: the budget alone
    (20000, 2.0, None, 20000),     # no asset count given: unchanged
])
def test_for_asset_caps_max_points(max_points, ppg, gaussians, expected):
    cfg = InferenceConfig(max_points=max_points, points_per_gaussian=ppg)
    got = cfg.for_asset(gaussians)
    assert got.max_points == expected
    assert got.points_per_gaussian == ppg and got.num_steps == cfg.num_steps  # nothing else moves
    light = LightFitConfig(max_points=max_points, points_per_gaussian=ppg)
    got = light.for_asset(gaussians)
    assert got.max_points == expected
    assert got.points_per_gaussian == ppg and got.identify_points == light.identify_points


def test_the_budget_samples_that_many_points():
    cfg = InferenceConfig(max_points=20000, points_per_gaussian=2.0).for_asset(2933)
    sub = subsample_indices(123539, cfg.max_points, cfg.seed)
    assert len(sub) == 5866 and len(set(sub.tolist())) == 5866


@pytest.mark.parametrize("bad", [0, -1.0])
def test_non_positive_budget_is_refused_naming_the_key(bad):
    with pytest.raises(ValueError, match="stage2.inference.points_per_gaussian must be positive or null"):
        InferenceConfig.from_mapping({"points_per_gaussian": bad})


@pytest.mark.parametrize("bad", [0, -1.0])
def test_light_fit_refuses_a_non_positive_budget_naming_the_key(bad):
    with pytest.raises(ValueError, match="method.points_per_gaussian must be positive or null"):
        LightFitConfig.from_mapping({"points_per_gaussian": bad})
