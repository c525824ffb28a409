"""experiments/training_pools/mix_conditions.py: the training view of each pool scene under its
reconstructed and its exact conditions (issue 42, session 18)."""
import json

import pytest

from experiments.training_pools.mix_conditions import mix_view


def _pool(root, names):
    root.mkdir()
    for n in names:
        (root / n).mkdir()
        (root / n / "gt_points.npz").write_text(root.name)
    (root / "splits.json").write_text(json.dumps({"train": names, "val": [], "test": []}))
    return root


def test_each_scene_appears_once_per_condition(tmp_path):
    recon = _pool(tmp_path / "rpool", ["p0", "p1"])
    exact = _pool(tmp_path / "pool", ["p0", "p1", "p2"])
    splits = mix_view(recon, exact, tmp_path / "mix")
    assert splits == {"train": ["p0", "p1", "exact_p0", "exact_p1"], "val": [], "test": []}
    assert json.loads((tmp_path / "mix" / "splits.json").read_text()) == splits
    # the links lead to the right pool: the reconstructed scene keeps its name, the exact one is prefixed
    assert (tmp_path / "mix" / "p1" / "gt_points.npz").read_text() == "rpool"
    assert (tmp_path / "mix" / "exact_p1" / "gt_points.npz").read_text() == "pool"
    assert mix_view(recon, exact, tmp_path / "mix") == splits  # rerun: same view


def test_a_scene_without_its_exact_twin_is_refused(tmp_path):
    recon = _pool(tmp_path / "rpool", ["p0", "p9"])
    exact = _pool(tmp_path / "pool", ["p0"])
    with pytest.raises(ValueError, match=r"pool/splits.json: no exact scene for \['p9'\]"):
        mix_view(recon, exact, tmp_path / "mix")


def test_a_link_to_another_pool_is_refused(tmp_path):
    recon = _pool(tmp_path / "rpool", ["p0"])
    exact = _pool(tmp_path / "pool", ["p0"])
    (tmp_path / "mix").mkdir()
    (tmp_path / "mix" / "exact_p0").symlink_to(recon / "p0")  # a stale view: the wrong condition
    with pytest.raises(FileExistsError, match=r"mix/exact_p0: exists and is not a link to .*pool/p0"):
        mix_view(recon, exact, tmp_path / "mix")
