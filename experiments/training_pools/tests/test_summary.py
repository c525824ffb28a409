"""experiments/training_pools/summary.py reads a run's held-out scores from its eval folder or from the
copy run.sh commits under results/heldout/cpu/ (the copy outlives the data folder): both give the
same units, and the scene average is the mean of the three channels."""
from __future__ import annotations

import json
import shutil

import pytest

from eval.records.points_scores import BASELINE_KEY
from experiments.training_pools.summary import units


def scores(seed: int) -> dict:
    scene = lambda a, r, m: {"albedo": {"psnr": a}, "roughness": {"psnr": r}, "metallic": {"psnr": m}}
    return {"train_seed": seed,
            "per_scene": {"stage2": {"p0224": scene(12.0, 15.0, 30.0), "p0225": scene(9.0, 10.0, 11.0)},
                          BASELINE_KEY: {"p0224": scene(10.0, 10.0, 10.0), "p0225": scene(8.0, 8.0, 8.0)}},
            "metal_iou": {"stage2": {"p0224": 0.75}}}


def test_units_from_folder_equal_units_from_the_kept_copy(tmp_path):
    folder = tmp_path / "run_s1" / "eval"
    folder.mkdir(parents=True)
    (folder / "scores.json").write_text(json.dumps(scores(1)))
    kept = tmp_path / "heldout" / "run_s1.json"
    kept.parent.mkdir()
    shutil.copy(folder / "scores.json", kept)
    assert units(folder) == units(kept)
    rows, iou, seed = units(kept)
    assert seed == 1 and iou == {"p0224": 0.75}
    assert rows[("p0224", 1)]["avg"] == pytest.approx(19.0)
    base, _, _ = units(kept, BASELINE_KEY)
    assert base[("p0225", 1)] == {"albedo": 8.0, "roughness": 8.0, "metallic": 8.0, "avg": 8.0}
