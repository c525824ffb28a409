"""`make demo`'s time, step by step: the demo's own recipe (``make -n -o install demo``: every
command `make demo` runs after the install, read from the Makefile so the two cannot drift), each
line run in order into a temporary demo folder and timed, wall and CPU (its processes' user +
system time, children included), with the machine and its load before and after named.

    python -m benchmarks.bench_demo [--record results/speed/cpu/demo.json] [--keep DIR] [--install]
    python -m benchmarks.bench_demo --install-only --record results/speed/cpu/demo.json

The CPU seconds say what the demo costs whatever else runs; the wall seconds are what a user
waits on this machine at this load. ``--install`` also times `make install` in a fresh clone of
the checkout's HEAD (a new .venv, the pip cache as this machine has it: what a new user's second
clone waits); ``--install-only`` times only that and replaces the install entry of an existing
record (with its own date and load). README's demo time is generated from the record (`make results`).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from datetime import date
from pathlib import Path

from benchmarks.common import REPO, machine


def demo_commands(demo: Path) -> list[str]:
    """The shell commands of `make demo` after its install, for the demo folder ``demo``
    (continuation lines joined; its comment lines dropped)."""
    out = subprocess.run(["make", "--no-print-directory", "-n", "-o", "install", "demo", f"DEMO={demo}"],
                         cwd=REPO, capture_output=True, text=True, check=True).stdout
    lines = re.sub(r"\\\n", " ", out).splitlines()
    return [c for c in lines if c.strip() and not c.lstrip().startswith("#")]  # make -n echoes comments


def step_name(command: str) -> str:
    """A short name for a recipe line: its gspi tool(s), else its first word."""
    tools = list(dict.fromkeys(re.findall(r"gspi-[a-z-]+", command)))
    return " + ".join(tools) if tools else command.split()[0]


def children_cpu() -> float:
    t = os.times()
    return t.children_user + t.children_system


def run_steps(commands: list[str], demo: Path, cwd: Path = REPO) -> list[dict]:
    steps = []
    for command in commands:
        wall, cpu = time.perf_counter(), children_cpu()
        done = subprocess.run(["bash", "-c", command], cwd=cwd, capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(cwd)})
        if done.returncode != 0:
            raise SystemExit(f"make demo's step failed ({done.returncode}): {command}\n{done.stderr[-3000:]}")
        step = {"step": step_name(command), "command": command.replace(str(demo), "<demo>"),
                "wall_s": round(time.perf_counter() - wall, 1), "cpu_s": round(children_cpu() - cpu, 1)}
        print(f"{step['step']:<32} {step['wall_s']:7.1f} s wall {step['cpu_s']:7.1f} s CPU", flush=True)
        steps.append(step)
    return steps


def time_install() -> dict:
    """`make install` in a fresh clone of this checkout's HEAD: wall and CPU seconds, its load."""
    with tempfile.TemporaryDirectory(prefix="gspi_bench_install_") as tmp:
        clone = Path(tmp) / "gspi"
        subprocess.run(["git", "clone", "--quiet", str(REPO), str(clone)], check=True)
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True,
                                check=True).stdout.strip()
        load_before = os.getloadavg()[0]
        step = run_steps(["make install"], clone, cwd=clone)[0]
    return {"wall_s": step["wall_s"], "cpu_s": step["cpu_s"], "commit": commit, "date": date.today().isoformat(),
            "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
            "what": "make install in a fresh clone, the pip cache as found"}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", type=Path, default=None, help="write the figures to this JSON file")
    ap.add_argument("--keep", type=Path, default=None, help="run the demo into this folder and keep it")
    ap.add_argument("--install", action="store_true", help="also time make install in a fresh clone")
    ap.add_argument("--install-only", action="store_true",
                    help="time only the install; replace the install entry of the existing --record")
    args = ap.parse_args(argv)
    print(machine())
    if args.install_only:
        if not (args.record and args.record.is_file()):
            raise SystemExit(f"--install-only updates an existing record: {args.record} is not a file")
        record = json.loads(args.record.read_text())
        record["install"] = time_install()
        print(f"make install in a fresh clone: {record['install']['wall_s']:.1f} s wall, {record['install']['cpu_s']:.1f} s CPU")
        args.record.write_text(json.dumps(record, indent=1) + "\n")
        return
    demo = args.keep.resolve() if args.keep else Path(tempfile.mkdtemp(prefix="gspi_bench_demo_"))
    load_before = os.getloadavg()[0]
    try:
        steps = run_steps(demo_commands(demo), demo)
    finally:
        if not args.keep:
            shutil.rmtree(demo, ignore_errors=True)
    record = {"machine": machine(), "date": date.today().isoformat(), "command": "python -m benchmarks.bench_demo",
              "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)], "steps": steps,
              "wall_s": round(sum(s["wall_s"] for s in steps), 1), "cpu_s": round(sum(s["cpu_s"] for s in steps), 1),
              "cores": os.cpu_count(), "install": time_install() if args.install else "not timed (make install before it)"}
    print(f"make demo without the install: {record['wall_s']:.1f} s wall, {record['cpu_s']:.1f} s CPU on "
          f"{record['cores']} cores (load {record['load_average'][0]:.1f} -> {record['load_average'][1]:.1f})")
    if args.record:
        args.record.parent.mkdir(parents=True, exist_ok=True)
        args.record.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
