"""Fixtures of the reliability corpus: every bad input is generated here, none committed."""
from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def tiny_gt(tmp_path_factory) -> Path:
    """One analytic sphere scene (32 px, 2 test views) + splits.json: a dataset gspi-eval scores
    in about a second with eval.channels=[roughness,metallic]."""
    from eval.common.atomic import write_json_atomic
    from tests.fixtures import make_scene

    root = tmp_path_factory.mktemp("rel_gt") / "gt"
    make_scene(root, "sphere_0", size=32, num_train=2, num_test=2)
    write_json_atomic(root / "splits.json", {"train": [], "val": [], "test": ["sphere_0"]})
    return root


@pytest.fixture
def workspace(tmp_path, tiny_gt) -> Path:
    """A user's folder: a copy of the ground truth and a prediction of it, under tmp_path."""
    import shutil

    from tests.fixtures import make_prediction

    shutil.copytree(tiny_gt, tmp_path / "gt")
    make_prediction(tmp_path / "gt", tmp_path / "pred", method="perturbed")
    return tmp_path

