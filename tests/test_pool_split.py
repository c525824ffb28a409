"""gspi.data.pool.split: train/val/test views of a training pool (symlinks + splits.json)."""
import json

import pytest

from gspi.data.pool.split import main, parse_range, split_view
from gspi.data.pool.training_pool import DONE_FILE


@pytest.fixture
def pool(tmp_path):
    root = tmp_path / "pool"
    names = [f"p{i:04d}_sphere_metal" for i in range(10)]
    for name in names:
        (root / name).mkdir(parents=True)
        (root / name / DONE_FILE).write_text("{}")
    (root / "splits.json").write_text(json.dumps({"train": names, "val": [], "test": []}))
    return root


def test_view_links_scenes_and_writes_disjoint_splits(pool, tmp_path):
    out = tmp_path / "view"
    main([str(pool), str(out), "--train", "0:4", "--test", "7:10"])
    splits = json.loads((out / "splits.json").read_text())
    assert splits == {"train": [f"p{i:04d}_sphere_metal" for i in range(4)], "val": [],
                      "test": [f"p{i:04d}_sphere_metal" for i in range(7, 10)]}
    assert (out / "p0008_sphere_metal").resolve() == (pool / "p0008_sphere_metal").resolve()
    assert not (out / "p0005_sphere_metal").exists()
    split_view(pool, out, {"train": range(4), "test": range(7, 10)})  # a rerun is idempotent


def test_overlapping_ranges_are_refused(pool, tmp_path):
    with pytest.raises(ValueError, match="train and test share pool indices"):
        split_view(pool, tmp_path / "v", {"train": range(0, 5), "test": range(4, 6)})


def test_range_past_the_pool_and_unfinished_scenes_are_named(pool, tmp_path):
    with pytest.raises(ValueError, match="has no pool scene 10"):
        split_view(pool, tmp_path / "v", {"test": range(8, 12)})
    (pool / "p0003_sphere_metal" / DONE_FILE).unlink()
    with pytest.raises(ValueError, match="p0003_sphere_metal: unfinished pool scene"):
        split_view(pool, tmp_path / "v", {"train": range(0, 4)})


@pytest.mark.parametrize("text", ["4", "a:b", "5:5", "-1:3"])
def test_bad_range_text(text):
    with pytest.raises(ValueError, match="pool range"):
        parse_range(text)
