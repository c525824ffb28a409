"""experiments/training_pools/run.sh names its views and runs from its settings (issue 42): the
64-scene names stay the ones earlier runs were trained under, TRAIN_SCENES names the larger
views, and a TRAIN_SCENES that SPLIT does not train on is refused before anything runs."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "run.sh"


def plan(tmp_path, script: Path = SCRIPT, **env) -> subprocess.CompletedProcess:
    """The script's PLAN_ONLY=1 output: what it would run, with nothing run (a None in `env`
    unsets that variable)."""
    full = {**os.environ, "WORK": str(tmp_path), "PLAN_ONLY": "1", **env}
    full = {k: v for k, v in full.items() if v is not None}
    return subprocess.run(["bash", str(script)], env=full, capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize("env, run, data", [
    ({}, "runs/cpu_parts_pool_s<seed>", "rpool64"),
    ({"CONDITIONS": "mixed"}, "runs/cpu_parts_pool_mix_s<seed>", "mix64"),
    ({"SPLIT": "--train 0:224", "TRAIN_SCENES": "224"}, "runs/cpu_parts_pool_224_s<seed>", "rpool224"),
    ({"SPLIT": "--train 0:224", "TRAIN_SCENES": "224", "CONDITIONS": "mixed", "ABLATION": "a2_no_view_onehot"},
     "runs/cpu_parts_pool_a2_no_view_onehot_mix224_s<seed>", "mix224"),
    ({"SPLIT": "--train 0:224", "TRAIN_SCENES": "224", "TAG": "pixel", "TRAIN_EXTRA": "stage2.data.pixel_features=true"},
     "runs/cpu_parts_pool_pixel_224_s<seed>", "rpool224"),
])
def test_run_and_view_names(tmp_path, env, run, data):
    out = plan(tmp_path, **env)
    assert out.returncode == 0, out.stderr
    assert f"{tmp_path}/{run} " in out.stdout and f"train data: {tmp_path}/{data};" in out.stdout, out.stdout


def test_train_extra_needs_a_tag_and_is_passed_on(tmp_path):
    out = plan(tmp_path, TRAIN_EXTRA="stage2.data.pixel_features=true")
    assert out.returncode == 2 and "needs a TAG" in out.stderr
    out = plan(tmp_path, TRAIN_EXTRA="stage2.data.pixel_features=true", TAG="pixel", ABLATION="a2_no_view_onehot")
    assert out.returncode == 0 and "runs/cpu_parts_pool_a2_no_view_onehot_pixel_s<seed>" in out.stdout
    assert "train extra: stage2.data.pixel_features=true" in out.stdout


def test_train_scenes_must_match_the_split(tmp_path):
    out = plan(tmp_path, TRAIN_SCENES="224")  # SPLIT keeps its default --train 0:64
    assert out.returncode == 2
    assert "TRAIN_SCENES=224" in out.stderr and "0:224" in out.stderr


def test_empty_seeds_build_the_data_and_train_nothing(tmp_path):
    """SEEDS="" rebuilds the pool and its reconstructions only (a lost data folder's rebuild);
    unset SEEDS trains the two default seeds."""
    assert "for seeds none (pool and reconstructions only);" in plan(tmp_path, SEEDS="").stdout
    out = plan(tmp_path, SEEDS=None)
    assert "for seeds 0 1;" in out.stdout, out.stdout
