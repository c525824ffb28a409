"""benchmarks/bench_demo.py times `make demo`'s own recipe (read from the Makefile, so the two
cannot drift), and README's demo time is generated from its record (gspi.publish)."""
from __future__ import annotations

from pathlib import Path

from benchmarks.bench_demo import demo_commands, run_steps, step_name
from gspi.publish.docs import demo_time_text


def test_the_steps_are_make_demos_after_the_install(tmp_path):
    commands = demo_commands(tmp_path / "demo")
    assert [step_name(c) for c in commands] == ["rm", "gspi-data", "gspi-run", "gspi-table",
                                                "gspi-relight + gspi-export", "gspi-report", "echo"]
    assert not any("make install" in c or "pip install" in c for c in commands)  # the install is not timed
    assert all(str(tmp_path / "demo") in c for c in commands[:4])  # every step writes into the given folder
    assert "+experiment=demo" in commands[2]


def test_steps_are_timed_in_wall_and_cpu_and_a_failure_names_its_command(tmp_path):
    import pytest

    steps = run_steps(["python3 -c 'sum(range(3_000_000))'", f"sleep 0.3; echo {tmp_path}"], tmp_path)
    assert steps[0]["cpu_s"] > 0 and steps[1]["wall_s"] >= 0.3 and steps[1]["cpu_s"] < 0.3
    assert steps[1]["command"] == "sleep 0.3; echo <demo>"  # no machine path in the record
    with pytest.raises(SystemExit, match="make demo's step failed .*: false"):
        run_steps(["false"], tmp_path)


def test_readme_demo_time_is_generated_from_the_record():
    rec = {"wall_s": 283.4, "cpu_s": 420.0, "cores": 2, "date": "2026-12-07", "command": "python -m benchmarks.bench_demo",
           "machine": "host: AMD EPYC, 2 cores", "load_average": [0.1, 1.9],
           "steps": [{"step": "rm", "wall_s": 0.0}, {"step": "gspi-data", "wall_s": 19.2},
                     {"step": "gspi-run", "wall_s": 201.0}]}
    text = demo_time_text(rec)
    assert "**4 min 43 s**" in text and "420 CPU-s on 2 cores" in text
    assert "gspi-data 19 s, gspi-run 201 s)" in text and "rm" not in text and "host" not in text
    assert "load average 0.1 -> 1.9" in text


def test_the_install_when_timed_is_added_to_the_demo_time():
    rec = {"wall_s": 262.3, "cpu_s": 400.8, "cores": 2, "date": "2026-12-07", "command": "python -m benchmarks.bench_demo",
           "machine": "host: AMD EPYC, 2 cores", "load_average": [0.9, 1.5], "steps": [{"step": "gspi-run", "wall_s": 183.0}],
           "install": {"wall_s": 77.4, "cpu_s": 74.9, "commit": "abc1234", "date": "2026-12-07", "load_average": [1.2, 1.4]}}
    text = demo_time_text(rec)
    assert "adds 77 s (75 CPU-s; 2026-12-07 at abc1234" in text and "**5 min 40 s** in all" in text
    rec["install"] = "not timed (make install before it)"
    assert "install in a fresh clone" not in demo_time_text(rec)


def test_install_only_needs_an_existing_record(tmp_path):
    import pytest

    from benchmarks.bench_demo import main

    with pytest.raises(SystemExit, match="--install-only updates an existing record: .*missing.json is not a file"):
        main(["--install-only", "--record", str(tmp_path / "missing.json")])
