"""`make demo`'s time, step by step: the demo's own recipe (``make -n -o install demo``: every
command `make demo` runs after the install, read from the Makefile so the two cannot drift), each
line run in order into a temporary demo folder and timed, wall and CPU (its processes' user +
system time, children included), with the machine and its load before and after named.

    python -m benchmarks.bench_demo [--record results/speed/cpu/demo.json] [--keep DIR]

The CPU seconds say what the demo costs whatever else runs; the wall seconds are what a user
waits on this machine at this load. The install (`make install`, a no-op on a warm checkout) is
not timed. README's demo time is generated from the record (`make results`).
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


def run_steps(commands: list[str], demo: Path) -> list[dict]:
    steps = []
    for command in commands:
        wall, cpu = time.perf_counter(), children_cpu()
        done = subprocess.run(["bash", "-c", command], cwd=REPO, capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)})
        if done.returncode != 0:
            raise SystemExit(f"make demo's step failed ({done.returncode}): {command}\n{done.stderr[-3000:]}")
        step = {"step": step_name(command), "command": command.replace(str(demo), "<demo>"),
                "wall_s": round(time.perf_counter() - wall, 1), "cpu_s": round(children_cpu() - cpu, 1)}
        print(f"{step['step']:<32} {step['wall_s']:7.1f} s wall {step['cpu_s']:7.1f} s CPU", flush=True)
        steps.append(step)
    return steps


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", type=Path, default=None, help="write the figures to this JSON file")
    ap.add_argument("--keep", type=Path, default=None, help="run the demo into this folder and keep it")
    args = ap.parse_args(argv)
    print(machine())
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
              "cores": os.cpu_count(), "install": "not timed (make install before it)"}
    print(f"make demo without the install: {record['wall_s']:.1f} s wall, {record['cpu_s']:.1f} s CPU on "
          f"{record['cores']} cores (load {record['load_average'][0]:.1f} -> {record['load_average'][1]:.1f})")
    if args.record:
        args.record.parent.mkdir(parents=True, exist_ok=True)
        args.record.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
