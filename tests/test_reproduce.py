"""gspi-reproduce (issue 53): one command per table, every step skipped when done, resumable.

The steps' logic on toy steps (markers, lanes, a changed command under the same work folder),
the committed scores made portable, the Table 2 plan on the committed scores, one-line errors,
and Table 2 at ``scale=smoke`` end to end: a table with bootstrap CIs, then a rerun that has
nothing left to do; an interrupted training resumed gives the scores of an uninterrupted run."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gspi.reproduce import table2

from gspi.cli import reproduce as cli
from gspi.reproduce.plan import Step, StepFailed, blocks, run_plan
from eval.portable import portable, portable_path
from tests.machine_paths import MACHINE_PATH

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def touch_command(path: Path) -> list[str]:
    return [sys.executable, "-c", f"import pathlib; pathlib.Path({str(path)!r}).write_text('x')"]


def test_steps_run_once_and_are_skipped_when_done(tmp_path):
    out = tmp_path / "a.txt"
    step = lambda: Step("make a", tmp_path / ".done" / "a", touch_command(out))  # noqa: E731
    assert run_plan([step()], tmp_path / "log") == ["make a"]
    assert out.read_text() == "x"
    out.unlink()
    assert run_plan([step()], tmp_path / "log") == []  # done: not run again
    assert not out.exists()
    assert "$ " in (tmp_path / "log").read_text()


def test_a_changed_command_under_the_same_work_folder_is_refused(tmp_path):
    run_plan([Step("make a", tmp_path / ".done" / "a", touch_command(tmp_path / "a"))], tmp_path / "log")
    with pytest.raises(StepFailed, match="was done by another command"):
        run_plan([Step("make a", tmp_path / ".done" / "a", touch_command(tmp_path / "b"))], tmp_path / "log")


def test_the_marker_names_programs_and_labelled_paths_not_this_machine(tmp_path):
    step = Step("s", tmp_path / "m", [sys.executable, "-m", "x", str(tmp_path / "work" / "f")],
                aliases={str(tmp_path / "work"): "<work>"})
    assert step.marker_text() == "python -m x '<work>/f'"


def test_a_failed_step_names_itself_and_its_log_and_leaves_no_marker(tmp_path):
    step = Step("boom", tmp_path / ".done" / "boom", [sys.executable, "-c", "raise SystemExit(3)"])
    with pytest.raises(StepFailed, match=r"step boom failed \(exit 3\).*its output"):
        run_plan([step], tmp_path / "log")
    assert not step.done.exists()


def test_a_step_another_call_is_running_is_refused_and_one_it_finished_is_skipped(tmp_path):
    import fcntl

    from gspi.reproduce.plan import run_step

    out = tmp_path / "a.txt"
    step = Step("train: full_s0", tmp_path / ".done" / "a", touch_command(out))
    lock = tmp_path / ".locks" / "train_full_s0.lock"
    lock.parent.mkdir()
    with open(lock, "w") as held:  # another call holds the step (flock: per open file, even in one process)
        held.write("pid 4242 since 2026-12-05T19:00:00Z\n")
        held.flush()
        fcntl.flock(held, fcntl.LOCK_EX)
        with pytest.raises(StepFailed, match=r"step train: full_s0 is being run by another gspi-reproduce on this "
                                             r"work folder \(pid 4242 since 2026-12-05T19:00:00Z; lock .*\): let it"):
            run_plan([step], tmp_path / "log")
        assert not out.exists() and not step.done.exists()
    run_plan([step], tmp_path / "log")  # released: runs, and leaves the lock file empty for the next holder
    assert out.read_text() == "x" and lock.read_text() == ""
    out.unlink()
    run_step(step, tmp_path / "log")  # finished by "another call" before this one got the lock: not run again
    assert not out.exists()


def test_a_run_another_call_holds_is_left_to_it_and_the_next_run_goes_on(tmp_path):
    """Two lanes on one work folder: a run's group (training, then measure) whose training another
    call holds is skipped whole, the other runs and the steps after them still run; an ungrouped
    step (data, Stage 0: what later steps need) held by another call still stops the call."""
    import fcntl

    s = lambda name, group=None: Step(name, tmp_path / ".done" / name, touch_command(tmp_path / name),  # noqa: E731
                                      lane_group=group)
    steps = [s("train: r0", "r0"), s("measure: r0", "r0"), s("train: r1", "r1"), s("measure: r1", "r1"), s("table")]
    (tmp_path / ".locks").mkdir()
    with open(tmp_path / ".locks" / "train_r0.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        assert run_plan(steps, tmp_path / "log") == ["train: r1", "measure: r1", "table"]
        assert not (tmp_path / "train: r0").exists() and not (tmp_path / "measure: r0").exists()
        with open(tmp_path / ".locks" / "data.lock", "w") as data_held:
            fcntl.flock(data_held, fcntl.LOCK_EX)
            with pytest.raises(StepFailed, match="step data is being run by another gspi-reproduce"):
                run_plan([s("data"), *steps], tmp_path / "log")
    assert run_plan(steps, tmp_path / "log") == ["train: r0", "measure: r0"]  # released: its turn


def test_a_step_repeats_until_done(tmp_path):
    counter = tmp_path / "n"
    bump = [sys.executable, "-c", f"import pathlib; p = pathlib.Path({str(counter)!r}); "
            "p.write_text(str(int(p.read_text()) + 1 if p.exists() else 1))"]
    step = Step("chunks", tmp_path / ".done" / "c", bump, repeat_until=lambda: int(counter.read_text()) >= 3)
    run_plan([step], tmp_path / "log")
    assert counter.read_text() == "3"


def test_lane_groups_form_blocks_and_run_side_by_side(tmp_path):
    s = lambda name, group=None: Step(name, tmp_path / ".done" / name, touch_command(tmp_path / name),  # noqa: E731
                                      lane_group=group)
    steps = [s("data"), s("t0", "r0"), s("m0", "r0"), s("t1", "r1"), s("m1", "r1"), s("table")]
    shape = [[[x.name for x in g] for g in block] for block in blocks(steps)]
    assert shape == [[["data"]], [["t0", "m0"], ["t1", "m1"]], [["table"]]]
    assert run_plan(steps, tmp_path / "log", lanes=2) == ["data", "t0", "m0", "t1", "m1", "table"]
    assert all((tmp_path / n).exists() for n in ("data", "t0", "m0", "t1", "m1", "table"))


def test_committed_scores_name_no_absolute_path(tmp_path):
    roots = {"<work>": tmp_path / "w"}
    assert portable_path(str(tmp_path / "w" / "runs" / "ckpt.pt"), roots) == "<work>/runs/ckpt.pt"
    assert portable_path("/somewhere/else/data/x", roots) == "<elsewhere>/data/x"
    assert portable({"a": ["/x/y/z", "rel", 3]}, {}) == {"a": ["<elsewhere>/y/z", "rel", 3]}
    assert portable_path("/" + "work/pool192", {}) == "<elsewhere>/pool192"  # never the machine's top folder
    assert portable_path("/top", {}) == "<elsewhere>/top"


def test_the_cpu_table2_plan_trains_only_what_is_not_committed(tmp_path, monkeypatch):
    """Table 2 at scale=cpu on a fresh clone: the committed scores stand for their runs (no
    training, no data for them); the other (variant, seed) pairs are planned."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    steps, cfg, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu"])
    scores = ROOT / cfg["scores_dir"]
    committed = {p.parent.name for p in scores.glob("*/scores.json")}
    assert {"a2_no_view_onehot_s0"} <= committed
    trained = {s.name.split(": ", 1)[1] for s in steps if s.name.startswith("train: ")}
    planned = {f"{v}_s{seed}" for v, seed in table2.run_order(cfg)}
    # every planned run without committed scores, but Full s0: the shipped checkpoint stands for it
    # (checkpoints_from), measured at most; true at any point of the table's progress. 18 paper rows'
    # runs (6 variants x 3 seeds) + the light-aware rows at 2 seeds (variant_seeds, issue 66)
    assert trained == planned - committed - {"full_s0"} and len(planned) == 18 + 4
    assert steps[-1].name == "table"
    for p in scores.glob("*/scores.json"):
        text = p.read_text()
        assert not MACHINE_PATH.search(text) and json.loads(text)["data"] == cfg["measure"]["data_label"], p


def test_the_cpu_table2_plan_trains_the_runs_the_table_needs_before_a4s_later_seeds(tmp_path, monkeypatch):
    """With no scores committed, every run is planned; A4's seeds 1 and 2 (run_last: the table
    needs A4 at >= 1 seed) come after all 16 others, which keep the seed-by-seed order."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    steps, cfg, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu", f"scores_dir={tmp_path / 'none'}",
                              "checkpoints_from=null"])
    order = [s.name.split(": ", 1)[1] for s in steps if s.name.startswith("train: ")]
    a4 = "a4_npts_1024_nlat_384"
    assert len(order) == 22 and order[-2:] == [f"{a4}_s1", f"{a4}_s2"]
    seeds = [int(name.rsplit("_s", 1)[1]) for name in order[:-2]]
    assert seeds == sorted(seeds) and order[0] == "full_s0" and f"{a4}_s0" in order[:6]
    # variant_seeds: the light-aware rows at seeds 0 and 1 only
    assert {n for n in order if n.startswith("light_")} == {"light_residual_s0", "light_residual_a2_s0",
                                                           "light_residual_s1", "light_residual_a2_s1"}


def test_a_dry_run_writes_nothing_and_lists_the_scores_it_would_adopt(tmp_path, monkeypatch, capsys):
    """``scores_from`` into an empty scores folder: the dry run names one ``adopt:`` step per run
    and writes no file; ``only=[adopt]`` then copies them (portable) and plans no training for them."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    scores = tmp_path / "scores"
    argv = [f"data_root={tmp_path}", "table=2", "scale=cpu", f"scores_dir={scores}", "seeds=[0]",
            "variants=[full,a1_no_global_prior]", "checkpoints_from=null",
            "scores_from={full_s0:results/heldout/cpu/stage2_pool224_pixel_5k/scores.json,"
            "a1_no_global_prior_s0:results/heldout/cpu/cpu_parts_pool_a1_no_global_prior_pixel_5k_224_s0/scores.json}"]
    assert cli.main([*argv, "dry_run=true"]) == 0
    out = capsys.readouterr().out
    assert "adopt: full_s0" in out and "adopt: a1_no_global_prior_s0" in out
    assert not scores.exists() and not (tmp_path / "reproduce").exists()
    assert cli.main([*argv, "only=[adopt]"]) == 0
    adopted = sorted(p.parent.name for p in scores.glob("*/scores.json"))
    assert adopted == ["a1_no_global_prior_s0", "full_s0"]
    assert not MACHINE_PATH.search((scores / "full_s0" / "scores.json").read_text())
    steps, _, _ = cli.plan(argv)
    assert [s.name for s in steps] == ["table"]  # adopted runs are neither trained nor measured


def test_the_measure_is_the_console_script_under_the_named_measure(tmp_path, capsys):
    """The measure step plans gspi-points-eval under conf/points_measure/table2 with the reproduce
    file's ``measure:`` keys as its overrides; at scale=cpu they are the committed scores' measure."""
    import yaml

    from eval.points_protocol import MEASURE_DEFAULTS, measure_hash, recorded_measure_hash

    assert cli.main(["table=2", "scale=smoke", f"data_root={tmp_path}", "dry_run=true"]) == 0
    line = next(l for l in capsys.readouterr().out.splitlines() if l.startswith("measure: full_s0"))
    assert f"{BIN / 'gspi-points-eval'} checkpoint=" in line and "evaluate_points" not in line
    assert "points_measure=table2 points_measure.num_steps=2 points_measure.max_points=500" in line
    _, cfg, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu"])
    group = yaml.safe_load((ROOT / "conf" / "points_measure" / "table2.yaml").read_text())
    planned = {**group, **{k: v for k, v in cfg["measure"].items() if k in MEASURE_DEFAULTS}}
    committed = json.loads((ROOT / "results/table2/cpu/full_s0/scores.json").read_text())
    assert measure_hash(planned) == recorded_measure_hash(committed)


def test_a_committed_checkpoint_stands_for_its_run_measured_and_never_trained(tmp_path, monkeypatch):
    """``checkpoints_from``: the shipped model is Full seed 0 of Table 2's recipe; with no committed
    scores it is measured on the work folder's held-out scenes (its checkpoint, not a run folder's),
    and a missing checkpoint is a one-line error naming the key."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    argv = [f"data_root={tmp_path}", "table=2", "scale=cpu", f"scores_dir={tmp_path / 'scores'}", "seeds=[0]",
            "variants=[full]"]
    steps, cfg, _ = cli.plan(argv)
    names = [s.name for s in steps]
    assert "measure: full_s0" in names and not any(n.startswith("train: ") for n in names)
    measure = steps[names.index("measure: full_s0")]
    assert f"checkpoint={ROOT / 'checkpoints' / 'stage2_pool224_pixel_5k.pt'}" in measure.command
    with pytest.raises(FileNotFoundError, match="checkpoints_from.full_s0: .*nope.pt does not exist"):
        cli.plan([*argv, "checkpoints_from={full_s0:checkpoints/nope.pt}"])
    assert cli.main([*argv, "checkpoints_from={full_s0:checkpoints/nope.pt}", "dry_run=true"]) == 2  # one line


def test_a_dry_run_says_how_far_each_begun_training_got(tmp_path, monkeypatch, capsys):
    """A training cut between chunks shows its last checkpoint's step; an unreadable checkpoint is
    named as such instead of failing the plan; a run not begun shows nothing."""
    import torch

    monkeypatch.setattr(cli, "REPO", ROOT)
    argv = [f"data_root={tmp_path}", "table=2", "scale=cpu", f"scores_dir={tmp_path / 'scores'}", "seeds=[5]",
            "variants=[full,a2_no_view_onehot,a3_npts_1024]"]
    runs = tmp_path / "reproduce" / "table2_cpu" / "runs_fast"
    (runs / "full_s5").mkdir(parents=True)
    torch.save({"step": 2750, "config": {"stage2": {"train": {"steps": 5000}}}}, runs / "full_s5" / "checkpoint.pt")
    (runs / "a2_no_view_onehot_s5").mkdir()
    (runs / "a2_no_view_onehot_s5" / "checkpoint.pt").write_bytes(b"half a file")
    assert cli.main([*argv, "dry_run=true"]) == 0
    begun = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("begun: "))
    assert begun.startswith("begun: train: full_s5 (at step 2750 of 5000); "
                            "train: a2_no_view_onehot_s5 (checkpoint unreadable: ")  # + the exception's class
    assert "a3_npts_1024_s5" not in begun


def test_the_cpu_rate_of_each_variant_comes_from_its_runs_folder_chunks(tmp_path):
    from gspi.reproduce.table2 import cpu_seconds_per_step

    chunks = [("data/reproduce/table2_cpu/runs_fast/full_s0", [0, 100], 100.0),
              ("data/reproduce/table2_cpu/runs_fast/full_s1", [100, 300], 500.0),
              ("<elsewhere>/runs_fast/a3_npts_1024_s1", [0, 50], 75.0),       # another data root: same folder name
              ("data/reproduce/table2_cpu/runs_fast_view/full_s0", [0, 10], 99.0),  # other conditions: not counted
              ("data/reproduce/table2_cpu/runs_fast/full_s2", [40, 40], 3.0)]       # no step taken
    log = tmp_path / "runs.jsonl"
    log.write_text("".join(json.dumps({"out": out, "steps": steps, "cpu_s_this_run": cpu}) + "\n"
                           for out, steps, cpu in chunks) + "\n")
    assert cpu_seconds_per_step(log, "runs_fast") == {"full": 2.0, "a3_npts_1024": 1.5}
    assert cpu_seconds_per_step(tmp_path / "none.jsonl", "runs_fast") == {}


def test_the_estimate_line_sums_every_step_by_what_it_does(tmp_path):
    from gspi.reproduce.plan import cost_line

    s = lambda name, cost: Step(name, tmp_path / name, touch_command(tmp_path / name),  # noqa: E731
                                cpu_s_left=(lambda: cost))
    line = cost_line([s("data: pool", 1800.0), s("stage 0: pool (recon=fast)", 3600.0), s("train: a", 3600.0),
                      s("train: b", 1800.0), s("train: c", None), s("table1: sweep (seeds 1)", 60.0),
                      Step("table", tmp_path / "t", touch_command(tmp_path / "t"))])
    assert line.startswith("estimate: ~3.0 CPU-h for 5 of 7 step(s) listed (data 30 CPU-min, stage 0 1.0 CPU-h, "
                           "train 1.5 CPU-h, sweep 1 CPU-min); wall time: ")
    assert line.endswith("; no estimate for train: c, table")


REPRODUCE_FILES = sorted(p.stem for p in (ROOT / "conf" / "reproduce").glob("table*_*.yaml"))


@pytest.mark.parametrize("name", REPRODUCE_FILES)
def test_every_table_and_scale_estimates_every_step_it_lists(name, tmp_path, monkeypatch, capsys):
    """The dry run prints each step's estimate and their sum: data, Stage 0, trainings, measures and
    the table all counted (issue 68: the data and Stage 0 steps were left out, smoke had none). An
    empty scores folder, so Tables 1 and 3 list their sweeps too."""
    from gspi.reproduce.plan import format_cpu, step_costs

    monkeypatch.setattr(cli, "REPO", ROOT)
    table, scale = name[5], name.split("_", 1)[1]
    argv = [f"table={table}", f"scale={scale}", f"data_root={tmp_path}", f"scores_dir={tmp_path / 'scores'}"]
    assert cli.main([*argv, "dry_run=true"]) == 0
    out = capsys.readouterr().out
    steps = [s for s in cli.plan(argv)[0] if not s.is_done()]
    costs = step_costs(steps)
    assert all(c is not None and c > 0 for c in costs.values()), costs
    for step in steps:
        assert f"{step.name} [{format_cpu(costs[step.name])}]: " in out
    total = next(line for line in out.splitlines() if line.startswith("estimate: "))
    assert total.startswith(f"estimate: {format_cpu(sum(costs.values()))} for {len(steps)} of {len(steps)} step(s)")
    assert "no estimate" not in out
    kinds = {s.name.split(":")[0].split(" (")[0] for s in steps}
    assert ({"data", "stage 0", "train", "measure", "table"} if table == "2" else {"data", "table"}) <= kinds


def test_the_table2_estimate_counts_its_scenes_and_the_run_logs_rates(tmp_path, monkeypatch):
    """Data and Stage 0 scale with the pools' scenes (gspi/reproduce/costs.py), a training with its
    variant's CPU-seconds per step in the run log."""
    from gspi.reproduce.costs import rate
    from gspi.reproduce.plan import step_costs

    monkeypatch.setattr(cli, "REPO", ROOT)
    argv = [f"data_root={tmp_path}", "table=2", "scale=cpu", f"scores_dir={tmp_path / 'scores'}", "seeds=[5]",
            "variants=[full]", "kept_state=null"]
    costs = step_costs(cli.plan(argv)[0])
    assert costs["data: training pool"] == pytest.approx(224 * rate("cpu", "data: pool").cpu_s)
    assert costs["stage 0: held-out scenes (recon=fast)"] == pytest.approx(32 * rate("cpu", "stage 0").cpu_s)
    assert costs["measure: full_s5"] == pytest.approx(32 * rate("cpu", "measure").cpu_s)
    assert 1800 < costs["train: full_s5"] < 5 * 3600  # the run log: 50-130 CPU-min a Full training


def test_a1_drops_the_pixel_features_it_cannot_use(tmp_path, monkeypatch):
    """A1 has no prior encoder, so no map to sample: its trainings turn the recipe's
    pixel_features off (variant_overrides), every other variant keeps the recipe."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    steps, _, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu", "seeds=[5]",
                            "variants=[full,a1_no_global_prior,a4_npts_1024_nlat_384]"])
    train = {s.name: list(map(str, s.command)) for s in steps if s.name.startswith("train: ")}
    assert "stage2.data.pixel_features=false" in train["train: a1_no_global_prior_s5"]
    assert not any("pixel_features" in a for a in train["train: full_s5"])
    assert "stage2=cpu_pool224_pixel_5k" in train["train: full_s5"]
    # A4's "384 latents" are 1.5x the paper's Full (256): 1.5x the recipe's 32 = 48 (docs/STAGE2.md)
    assert train["train: a4_npts_1024_nlat_384_s5"][-1] == "stage2.model.num_latents=48"
    assert not any("num_latents" in a for a in train["train: full_s5"])


def test_the_light_rows_read_stage1_of_the_pools_assets_planned_before_they_train(tmp_path, monkeypatch):
    """The light-aware rows read their condition as a run reads it (``light_geometry=asset``): the
    plan writes Stage I of both pools' assets before any training; a plan without them does not."""
    monkeypatch.setattr(cli, "REPO", ROOT)
    steps, _, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu", "seeds=[0]", "variants=[light_residual]"])
    names = [s.name for s in steps]
    first_train = next(k for k, n in enumerate(names) if n.startswith("train: "))
    assert names.index("stage 1: training pool's assets") < first_train
    assert names.index("stage 1: held-out assets") < first_train
    stage1 = next(s for s in steps if s.name == "stage 1: training pool's assets")
    assert list(map(str, stage1.command))[-2:] == ["gspi.stage1.pool_clouds", str(tmp_path / "reproduce" / "table2_cpu" / "rtrain_fast")]
    train = next(s for s in steps if s.name == "train: light_residual_s0")
    assert "stage2.data.light_geometry=asset" in list(map(str, train.command))
    # the light rows train the known-light study's best recipe: the scene-level metal test, gated
    for variant in ("light_residual", "light_residual_a2"):
        steps, _, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu", "seeds=[1]", f"variants=[{variant}]"])
        train = list(map(str, next(s for s in steps if s.name == f"train: {variant}_s1").command))
        assert {"stage2.data.light_metal_min_evidence=1.1", "stage2.diffusion.readout_metal_gate=true",
                f"ablation={variant}"} <= set(train)
    plain, _, _ = cli.plan([f"data_root={tmp_path}", "table=2", "scale=cpu", "seeds=[5]", "variants=[full]"])
    assert not any(s.name.startswith("stage 1:") for s in plain)


@pytest.mark.parametrize("argv, message", [
    (["table=9", "scale=cpu"], "no conf/reproduce/table9_cpu.yaml; known: model=default scale=cpu, table=1 scale=cpu"),
    (["model=best", "scale=cpu"], "model=best scale=cpu: no conf/reproduce/model_best_cpu.yaml"),
    (["table=2"], "needs table=N (or model=NAME) and scale=S"),
    (["scale=cpu"], "needs table=N (or model=NAME) and scale=S"),
    (["table=2", "model=default", "scale=cpu"], "needs table=N (or model=NAME) and scale=S"),
    (["table=2", "scale=smoke", "seedz=[1]"], "table2_smoke"),
    (["table2"], "expected key=value"),
    (["table=2", "scale=smoke", "keep_state=maybe"], "keep_state='maybe': expected true or false"),
    (["table=2", "scale=smoke", "dry_run=1"], "dry_run=1: expected true or false"),
])
def test_a_bad_call_is_one_line_and_exit_2(argv, message, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and err[0].startswith("gspi-reproduce: error:")


def test_help_prints_the_commands_and_exits_0(capsys):
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("gspi-reproduce:") and "gspi-reproduce table=2 scale=cpu keep_state=true" in out


def reproduce(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run([str(BIN / "gspi-reproduce"), *args], cwd=cwd, env=env, capture_output=True, text=True)


def test_table2_smoke_end_to_end_gives_a_table_with_cis_and_then_nothing_to_do(tmp_path):
    proc = reproduce("table=2", "scale=smoke", "seeds=[0]", f"data_root={tmp_path}")  # one seed: CI's time
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = (tmp_path / "reproduce" / "table2_smoke" / "tables" / "table2.md").read_text()
    assert "GS-PI (ours, Full)" in table and "A1: w/o global semantic prior" in table
    a1_row = table.split("A1:")[1].split("\n")[0]
    assert "| 2 |" in a1_row and "[" in a1_row  # 2 scenes x 1 seed, a bootstrap CI against Full
    assert "done: table 2 at scale smoke" in proc.stdout
    again = reproduce("table=2", "scale=smoke", "seeds=[0]", f"data_root={tmp_path}", "dry_run=true")
    assert again.returncode == 0 and "1 step(s) to do" in again.stdout  # only the table, rebuilt each call


@pytest.mark.slow
def test_an_interrupted_training_resumes_to_the_uninterrupted_scores(tmp_path):
    """The same smoke table twice: straight through, and with Full's training stopped half-way
    (stage2.train.stop_at, as a cut-off chunk leaves it) before the command is run again."""
    keys = ["table=2", "scale=smoke", "variants=[full]", "seeds=[0]", "train_overrides=['stage2.train.steps=6','stage2.data.num_points=32']"]
    straight = reproduce(*keys, f"data_root={tmp_path / 'a'}")
    assert straight.returncode == 0, straight.stderr[-3000:]
    first = reproduce(*keys, f"data_root={tmp_path / 'b'}", "only=[data,stage]")
    assert first.returncode == 0, first.stderr[-3000:]
    work = tmp_path / "b" / "reproduce" / "table2_smoke"
    cut = subprocess.run([str(BIN / "gspi-train"), f"data={work / 'rtrain_tiny'}", f"out={work / 'runs_tiny' / 'full_s0'}",
                          "stage2=tiny", "ablation=full", "seed=0", "stage2.train.steps=6",
                          "stage2.data.num_points=32", "stage2.train.stop_at=3"], capture_output=True, text=True)
    assert cut.returncode == 0, cut.stderr[-3000:]
    resumed = reproduce(*keys, f"data_root={tmp_path / 'b'}")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert json.loads((work / "runs_tiny" / "full_s0" / "stats.json").read_text())["resumed_from"] == 3
    a, b = (json.loads((tmp_path / r / "reproduce" / "table2_smoke" / "scores" / "full_s0" / "scores.json").read_text())
            for r in ("a", "b"))
    assert a["per_scene"] == b["per_scene"]


def test_worker_counts_and_chunk_lengths_do_not_change_a_steps_identity(tmp_path):
    done = tmp_path / ".done" / "d"
    Step("d", done, [sys.executable, "-m", "x", "data.workers=2", "--workers", "2", "k=1"])
    run = lambda argv: run_plan([Step("d", done, argv)], tmp_path / "log")  # noqa: E731
    done.parent.mkdir(parents=True)
    done.write_text("2026-01-01T00:00:00Z python -m x data.workers=2 --workers 2 k=1\n")
    assert run([sys.executable, "-m", "x", "data.workers=1", "--workers", "1", "k=1"]) == []
    with pytest.raises(StepFailed, match="another command"):
        run([sys.executable, "-m", "x", "data.workers=1", "k=2"])
