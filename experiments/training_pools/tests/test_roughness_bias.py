"""experiments/training_pools/roughness_bias.py: means over the masked test pixels, the run's PSNR, errors."""
import json

import numpy as np
import pytest

from eval.common.imageio import write_png
from experiments.training_pools.roughness_bias import main, roughness_rows


def _view(view_dir, roughness, mask=None):
    view_dir.mkdir(parents=True)
    write_png(view_dir / "roughness.png", roughness[..., None])
    if mask is not None:
        write_png(view_dir / "mask.png", mask[..., None])


@pytest.fixture
def dataset_and_run(tmp_path):
    data, run = tmp_path / "data", tmp_path / "run"
    data.mkdir()
    (data / "splits.json").write_text(json.dumps({"train": [], "test": ["a"]}))
    mask = np.zeros((4, 4), np.float32)
    mask[:2] = 1.0
    gt = np.full((4, 4), 0.2, np.float32)
    gt[:2, :2] = 1.0  # foreground: four at 1.0, four at 0.2 -> mean 0.6
    pred = np.full((4, 4), 0.0, np.float32)
    pred[:2] = 0.4  # background pixels (0.0) must not count
    for v in ("t00", "t01"):
        _view(data / "a" / "test" / v, gt, mask)
        _view(run / "predictions" / "a" / "test" / v, pred)
    (run / "eval").mkdir()
    (run / "eval" / "eval_meta.json").write_text(json.dumps({"per_scene": {"a": {"roughness": {"psnr": 7.5}}}}))
    return data, run


def test_rows_average_the_foreground_of_every_test_view(dataset_and_run):
    data, run = dataset_and_run
    (row,) = roughness_rows(data, {"m": run})
    assert row["scene"] == "a"
    assert row["gt"][0] == pytest.approx(0.6, abs=2e-3) and row["gt"][1] == pytest.approx(0.4, abs=2e-3)
    mean, std, psnr = row["m"]
    assert mean == pytest.approx(0.4, abs=2e-3) and std == pytest.approx(0.0, abs=1e-6) and psnr == 7.5


def test_a_folder_without_scores_is_a_one_line_error(dataset_and_run, tmp_path, capsys):
    data, _ = dataset_and_run
    with pytest.raises(SystemExit):
        main(["--data", str(data), f"m={tmp_path}"])
    assert "has no eval/eval_meta.json" in capsys.readouterr().err
