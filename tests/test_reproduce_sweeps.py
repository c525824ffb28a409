"""gspi-reproduce for the sweep tables (Tables 1 and 3, ``gspi.reproduce.sweep_tables``): which
seeds a call still runs, and what it commits. Toy records (a ``result.json`` naming its seed),
no pipeline run."""
from __future__ import annotations

import json
from pathlib import Path

from gspi.cli import reproduce as cli
from gspi.reproduce.sweep_tables import commit_sweep_records, committed_seeds, seeds_to_run

ROOT = Path(__file__).resolve().parents[1]


def write_record(folder: Path, seed: int, data: str) -> None:
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps({"seed": seed, "data": data, "status": "ok"}))


def test_only_the_seeds_without_committed_records_are_run(tmp_path):
    scores = tmp_path / "scores"
    assert seeds_to_run({"seeds": [0, 1, 2]}, scores) == [0, 1, 2]
    assert seeds_to_run({"seeds": None}, scores) is None  # no seeds named: the run config's, once
    write_record(scores / "ablation=full", 0, "x")
    assert committed_seeds(scores) == {0}
    assert seeds_to_run({"seeds": [2, 0, 1]}, scores) == [1, 2]
    assert seeds_to_run({"seeds": None}, scores) == []  # a committed record stands
    write_record(scores / "ablation=full,seed=1", 1, "x")
    write_record(scores / "ablation=full,seed=2", 2, "x")
    assert seeds_to_run({"seeds": [0, 1, 2]}, scores) == []


def test_a_commit_copies_the_seeds_it_ran_with_portable_paths_and_leaves_the_others(tmp_path):
    runs, scores = tmp_path / "work" / "runs", tmp_path / "scores"
    write_record(runs / "ablation=full", 0, str(tmp_path / "work" / "data"))
    write_record(runs / "ablation=full,seed=1", 1, str(tmp_path / "work" / "data"))
    write_record(scores / "ablation=full", 0, "<work>/data (committed earlier)")
    written = commit_sweep_records(runs, scores, {"<work>": tmp_path / "work"}, seeds=[1])
    assert [p.name for p in written] == ["ablation=full,seed=1"]
    assert json.loads((scores / "ablation=full,seed=1" / "result.json").read_text())["data"] == "<work>/data"
    assert json.loads((scores / "ablation=full" / "result.json").read_text())["data"] == \
        "<work>/data (committed earlier)"  # a committed seed is never rewritten
    assert len(commit_sweep_records(runs, scores, {"<work>": tmp_path / "work"})) == 2  # no seeds: every job


def test_table3_plans_the_seeds_not_committed_and_names_them_in_its_steps(tmp_path, monkeypatch):
    """Table 3 at scale=cpu: its committed records' seeds are not run again; the sweep of the
    others passes ``seed=a,b`` and its markers name those seeds (a marker of an earlier seed set
    is never taken for this one)."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    steps, cfg, _ = cli.plan([f"data_root={tmp_path}", "table=3", "scale=cpu"])
    missing = sorted(set(cfg["seeds"]) - committed_seeds(ROOT / cfg["scores_dir"]))
    names = [s.name for s in steps]
    if not missing:
        assert names == ["table"]
        return
    sweep = next(s for s in steps if s.name.startswith("table3: sweep"))
    assert sweep.command[-1] == f"seed={','.join(map(str, missing))}"
    assert sweep.done.name == "sweep_s" + "_".join(map(str, missing))
    assert names[-1] == "table"


def test_a_launcher_worker_count_does_not_change_a_sweeps_identity(tmp_path, monkeypatch):
    monkeypatch.setattr(cli, "REPO", ROOT)
    scores = tmp_path / "none"
    one, _, _ = cli.plan([f"data_root={tmp_path}", "table=3", "scale=cpu", "workers=1", f"scores_dir={scores}"])
    two, _, _ = cli.plan([f"data_root={tmp_path}", "table=3", "scale=cpu", "workers=2", f"scores_dir={scores}"])
    assert "hydra.launcher.n_jobs=1" in one[1].command and "hydra.launcher.n_jobs=2" in two[1].command
    assert one[1].marker_text() == two[1].marker_text()
    assert one[1].command[-1] == "seed=0,1,2"
