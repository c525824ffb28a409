"""Class 1, stale results: a job removes its old record before it writes, and a kill at any
point leaves no record that describes other files. One kill-and-rerun test per CLI that writes
results (gspi-run, gspi-eval, gspi-table, gspi-train, gspi-data). A kill is simulated by a
KeyboardInterrupt raised inside the CLI at a chosen point (nothing after it runs, as with
SIGKILL; `except Exception` handlers do not catch it)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.reliability.helpers import EVAL_FAST, assert_written_only_under, run_cli, snapshot
from tests.run_helpers import TINY_RUN


def _kill(*_args, **_kwargs):
    raise KeyboardInterrupt("simulated kill")


# --- gspi-run -----------------------------------------------------------------------------

def test_gspi_run_removes_the_old_record_before_it_writes(micro_dataset, tmp_path, monkeypatch):
    """The protocol without a real run (fast): a job of config B in a folder holding A's
    complete record and scores, killed as soon as it starts its method, leaves neither A's
    record nor A's scores; A's rerun is then not "complete, skipped"."""
    from eval.common.atomic import write_json_atomic
    from gspi.run.methods import InhouseMethod
    from gspi.run.record import config_hash, is_complete, write_result
    from gspi.run.runner import run_job
    from tests.run_helpers import run_config

    out = tmp_path / "job"
    config_a = run_config(micro_dataset, out, ["method=no_decomposition", "figures=false"])
    hash_a = config_hash(config_a)
    write_json_atomic(out / "eval" / "summary.json", {"albedo": {"psnr": 30.0, "ssim": 0.9, "lpips": 0.1}})
    (out / "predictions" / "scene_of_a").mkdir(parents=True)
    write_json_atomic(out / "predictions" / "scene_of_a" / "meta.json", {"method": "m", "config_hash": hash_a})
    write_result(out, status="complete", cfg_hash=hash_a, method="no_decomposition", ablation="full", table=None,
                 seed=0, data=str(micro_dataset), scenes=["scene_of_a"], material_eval="eval")
    assert is_complete(out, hash_a)
    monkeypatch.setattr(InhouseMethod, "prepare", _kill)
    with pytest.raises(KeyboardInterrupt):
        run_job(run_config(micro_dataset, out, ["method=no_decomposition", "figures=false", "seed=1"]))
    assert not (out / "result.json").exists() and not (out / "eval" / "summary.json").exists()
    assert not (out / "predictions" / "scene_of_a").exists() and not is_complete(out, hash_a)


@pytest.mark.slow
def test_gspi_run_killed_rerun_of_another_config_leaves_no_stale_record(micro_dataset, tmp_path, monkeypatch):
    """The issue's case: config B into A's folder, killed after eval/ is written. Before the
    fix A's result.json stayed beside B's scores: gspi-table showed them and a rerun of A said
    "complete, skipped"."""
    import gspi.run.runner as runner
    from gspi.cli.run import main
    from gspi.run.record import read_result

    out = tmp_path / "runs" / "job"
    config_a = [f"data={micro_dataset}", f"out={out}", *TINY_RUN, "method=no_decomposition", "figures=false"]
    code, text = run_cli(main, config_a)
    assert code == 0, text[-3000:]
    record_a = read_result(out)
    assert record_a["status"] == "complete"

    # a file only A's prediction has: B (a method writing fewer files) must not inherit it
    stray = next((out / "predictions").iterdir()) / "test" / "t00" / "stale_from_config_a.png"
    stray.write_bytes(b"A")
    monkeypatch.setattr(runner, "points_summary", _kill)  # after eval/ is written, before result.json
    code, text = run_cli(main, config_a + ["seed=1"])  # a kill is one line and exit 130 (issue 54)
    assert code == 130, text[-2000:]
    monkeypatch.undo()
    assert not stray.exists()
    assert (out / "eval" / "summary.json").is_file()  # B's scores ...
    assert not (out / "result.json").exists()          # ... and no record claiming them (or A)
    meta = json.loads((out / "eval" / "eval_meta.json").read_text())
    assert meta["config_hash"] != record_a["config_hash"]  # the scores name their config

    # gspi-table: the killed job is listed as unfinished, never tabulated as A
    from eval.tables.cli import main as table_main
    code, text = run_cli(table_main, [str(tmp_path / "runs"), f"out={tmp_path / 'tables'}"])
    assert "without result.json" in text or "unfinished" in text, text[-2000:]
    assert not (tmp_path / "tables" / "table1.md").exists() or \
        "no_decomposition" not in (tmp_path / "tables" / "table1.md").read_text()

    # rerunning A redoes it (not "complete, skipped"), and the record describes A's files
    code, text = run_cli(main, config_a)
    assert code == 0 and "skipped" not in text, text[-3000:]
    record = read_result(out)
    assert record["status"] == "complete" and record["config_hash"] == record_a["config_hash"]
    meta = json.loads((out / "eval" / "eval_meta.json").read_text())
    assert meta["config_hash"] == record_a["config_hash"]
    for scene_meta in (out / "predictions").glob("*/meta.json"):
        assert json.loads(scene_meta.read_text())["config_hash"] == record_a["config_hash"]


# --- gspi-eval ----------------------------------------------------------------------------

def test_gspi_eval_killed_rerun_leaves_no_old_summary(workspace):
    """Before the fix: new .hydra/, old summary.json (gspi-table read it as the new run)."""
    import eval.cli as cli

    out = workspace / "ev"
    argv = [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={out}", *EVAL_FAST]
    code, text = run_cli(cli.main, argv)
    assert code == 0 and (out / "summary.json").is_file(), text[-2000:]
    import unittest.mock as mock
    with mock.patch.object(cli, "evaluate", _kill):  # a kill is one line and exit 130 (issue 54)
        killed, killed_text = run_cli(cli.main, argv[:-1] + ["eval.channels=[roughness]"])
    assert killed == 130, killed_text[-2000:]
    assert not (out / "summary.json").exists() and not (out / "eval_meta.json").exists()
    code, text = run_cli(cli.main, argv[:-1] + ["eval.channels=[roughness]"])
    assert code == 0, text[-2000:]
    assert set(json.loads((out / "summary.json").read_text())) == {"roughness"}
    meta = json.loads((out / "eval_meta.json").read_text())
    assert meta["protocol_config"]["channels"] == ["roughness"]


# --- gspi-table ---------------------------------------------------------------------------

def test_gspi_table_killed_while_writing_keeps_the_previous_table(workspace):
    """A table file is replaced whole or not at all; no temporary file is left behind."""
    import unittest.mock as mock

    import eval.common.atomic as atomic
    import eval.cli as cli
    from eval.tables.cli import main as table_main

    run_cli(cli.main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}", *EVAL_FAST])
    tables = workspace / "tables"
    code, text = run_cli(table_main, [str(workspace / "ev"), f"out={tables}"])
    assert code == 0, text[-2000:]
    before = snapshot(tables)
    with mock.patch.object(atomic.os, "replace", _kill):  # a kill is one line and exit 130 (issue 54)
        killed, killed_text = run_cli(table_main, [str(workspace / "ev"), f"out={tables}"])
    assert killed == 130, killed_text[-2000:]
    assert snapshot(tables) == before  # old files whole, no .tmp left
    code, _ = run_cli(table_main, [str(workspace / "ev"), f"out={tables}"])
    assert code == 0 and {p for p in before} == set(snapshot(tables))


# --- gspi-train ---------------------------------------------------------------------------

TRAIN_TINY = ["stage2=tiny", "stage2.train.steps=4", "stage2.eval.enabled=false"]


def test_gspi_train_killed_while_saving_then_rerun(micro_dataset, tmp_path):
    """A kill inside the checkpoint write leaves no partial checkpoint and no stats.json of an
    earlier run; the rerun finishes and writes both."""
    import unittest.mock as mock

    import gspi.stage2.checkpoint as checkpoint
    from gspi.cli.train import main

    out = tmp_path / "s2"
    out.mkdir()
    (out / "stats.json").write_text('{"final_loss": 0.1, "from": "an earlier run"}\n')  # the old record
    argv = [f"data={micro_dataset}", f"out={out}", *TRAIN_TINY]
    real_save = checkpoint.torch.save

    def save_half_then_die(obj, path, *a, **k):
        Path(path).write_bytes(b"half a checkpoint")
        raise KeyboardInterrupt("simulated kill")

    with mock.patch.object(checkpoint.torch, "save", save_half_then_die):  # a kill is one line and exit 130 (issue 54)
        killed, killed_text = run_cli(main, argv)
    assert killed == 130, killed_text[-2000:]
    assert not (out / "checkpoint.pt").exists() and not (out / "stats.json").exists()
    assert not list(out.glob(".checkpoint.pt.*"))  # no temporary left
    assert checkpoint.torch.save is real_save
    code, text = run_cli(main, argv)
    assert code == 0 and (out / "checkpoint.pt").is_file(), text[-2000:]
    assert "earlier run" not in (out / "stats.json").read_text()


# --- gspi-data ----------------------------------------------------------------------------

def test_gspi_data_killed_regeneration_leaves_no_old_splits(tmp_path):
    """splits.json is the dataset's record: a regeneration killed after its first scene must
    not leave the old splits beside new scenes; the rerun completes the dataset."""
    import unittest.mock as mock

    import gspi.data.generate as generate
    from gspi.cli.data import main
    from tests.run_helpers import MICRO_DATA

    out = tmp_path / "data"
    out.mkdir()
    (out / "splits.json").write_text('{"train": ["old_scene"], "val": [], "test": []}\n')  # the old record
    argv = ["preset=tiny", f"out={out}", "seed=1", *MICRO_DATA, "data.point_clouds=false",
            "data.num_train_scenes=1", "data.num_test_views=1", "data.image_size=16", "data.env_height=8"]
    real = generate._make_scene
    calls = []

    def die_after_first(*a, **k):
        if calls:
            raise KeyboardInterrupt("simulated kill")
        calls.append(1)
        return real(*a, **k)

    with mock.patch.object(generate, "_make_scene", die_after_first):  # a kill is one line and exit 130 (issue 54)
        killed, killed_text = run_cli(main, argv)
    assert killed == 130, killed_text[-2000:]
    assert not (out / "splits.json").exists()  # the first new scene is on disk: no old splits beside it
    before = snapshot(tmp_path)
    code, text = run_cli(main, argv)
    assert code == 0, text[-2000:]
    splits = json.loads((out / "splits.json").read_text())
    assert "old_scene" not in str(splits)
    assert all((out / n / "scene.json").is_file() for names in splits.values() for n in names)
    assert_written_only_under(before, snapshot(tmp_path), "data")
