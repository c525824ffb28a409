"""A reproduction as a list of steps, each a product command with the output that marks it done.

``gspi-reproduce`` (gspi/cli/reproduce.py) turns a table's config into ``Step``s and runs them in
order. A step is skipped when its ``done`` file exists, so rerunning the same command after an
interruption continues the work; a step whose command is cut off writes no ``done`` and is run
again (every command it runs resumes itself: gspi-data keeps finished scenes, the pool
reconstruction finished assets, gspi-train its ``checkpoint.pt``). A step may need several calls
of its command (a training run in chunks of ``stage2.train.stop_after_minutes``): ``repeat_until``
says when it is done. Each command is logged before it runs, so the log reads as the commands a
person would type.

Two calls may share a work folder (two scales whose runs live side by side, or a second call
with other ``variants=``/``seeds=`` to use a free core): each step runs under an exclusive lock
(``<work>/.locks/<step>.lock``, ``fcntl.flock``, released by the OS when its process dies), so no
step runs twice: a run (training and measure) another call is running is left to it and this call
goes on with the next run; a data or Stage 0 step another call is running stops this call with one
line (what follows needs it); a step the other call finished meanwhile is skipped. flock is per
machine: on a cluster, give each job its own steps (SLURM: docs/REPRODUCE.md "On a cluster").
"""
from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, Sequence

log = logging.getLogger(__name__)
# arguments that change how fast a command runs, not what it writes: left out of the markers, so a
# rerun with another worker count or chunk length continues the same work
SPEED_ONLY = ("data.workers=", "stage2.train.stop_after_minutes=", "hydra.launcher.n_jobs=")
SPEED_ONLY_FLAGS = ("--workers",)  # followed by their value
# arguments that say where configs are found, not what they say (a study's folder: gspi-reproduce
# study=): left out of the markers too, so a checkout elsewhere continues the same work
WHERE_ONLY = ("hydra.searchpath=",)


@dataclass
class Step:
    """One step: ``command`` (argv) or ``action`` (in-process), finished when ``done`` exists."""

    name: str
    done: Path
    command: Optional[Sequence[str]] = None
    action: Optional[Callable[[], None]] = None
    repeat_until: Optional[Callable[[], bool]] = None  # None: one successful call finishes the step
    after: Optional[Callable[[], None]] = None  # runs once the command is done (e.g. writes ``done``)
    env: dict = field(default_factory=dict)
    max_calls: int = 1000
    lane_group: Optional[str] = None  # consecutive steps with a group run as lanes: groups side by side
    marker: bool = True  # ``done`` is a marker this module writes (with the command), not the step's output
    aliases: dict = field(default_factory=dict)  # path -> label in ``marker_text`` (e.g. the work folder -> <work>)
    rebuild: bool = False  # run on every call: its output is rebuilt from whatever exists (a table)
    progress: Optional[Callable[[], Optional[str]]] = None  # how far an unfinished step got (e.g. a training's step)
    cpu_s_left: Optional[Callable[[], Optional[float]]] = None  # CPU-seconds it still needs (None: no estimate)

    def describe(self) -> str:
        return shlex.join(map(str, self.command)) if self.command else f"({self.name}: in-process)"

    def marker_text(self) -> str:
        """The command as recorded in the marker: the program by name, paths by their labels and no
        ``SPEED_ONLY`` or ``WHERE_ONLY`` argument, so a moved work folder, another checkout or another worker count
        still recognises its own steps."""
        if self.command is None:
            return self.describe()
        argv = [str(a) for a in self.command]
        head = ["python"] if argv[0] == sys.executable else [Path(argv[0]).name]
        text = shlex.join(head + argv[1:])
        for path, label in sorted(self.aliases.items(), key=lambda kv: -len(kv[0])):
            text = text.replace(str(path), label)
        return without_speed_only(text)

    def is_done(self) -> bool:
        """Done; a marker left by another command is an error (the work folder holds other data)."""
        if self.rebuild or not self.done.exists():
            return False
        if self.marker and self.command is not None:
            recorded = without_speed_only(self.done.read_text().split(" ", 1)[-1].strip())
            if recorded != self.marker_text():
                raise StepFailed(f"step {self.name} was done by another command ({recorded}), not "
                                 f"{self.marker_text()}: a config key changed under the same work folder; "
                                 f"delete {self.done.parent.parent} or set another work folder")
        return True


def without_speed_only(command: str) -> str:
    """``command`` (shell words) without the ``SPEED_ONLY`` and ``WHERE_ONLY`` arguments."""
    kept, skip = [], False
    for arg in shlex.split(command):
        if skip or arg.startswith(SPEED_ONLY + WHERE_ONLY):
            skip = False
            continue
        if arg in SPEED_ONLY_FLAGS:
            skip = True
            continue
        kept.append(arg)
    return shlex.join(kept)


class StepFailed(RuntimeError):
    """A step's command exited non-zero: the message names the step, the command and its log."""


class StepBusy(StepFailed):
    """Another call holds the step's lock (it is running it right now)."""


@contextlib.contextmanager
def step_lock(step: Step, lock_dir: Path, *, wait: bool = False):
    """Holds ``<lock_dir>/<step name>.lock`` for this process; another holder means another call
    runs the step: ``StepFailed`` naming it (its pid and start), or, with ``wait``, waits for it."""
    lock_dir.mkdir(parents=True, exist_ok=True)
    path = lock_dir / (re.sub(r"[^A-Za-z0-9_.-]+", "_", step.name).strip("_") + ".lock")
    with open(path, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "pid unknown"
            raise StepBusy(f"step {step.name} is being run by another gspi-reproduce on this work folder "
                             f"({holder}; lock {path}): let it finish, or give this call other variants=/seeds=") from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()} since {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}\n")
        fh.flush()
        try:
            yield
        finally:
            fh.seek(0)
            fh.truncate()
            fcntl.flock(fh, fcntl.LOCK_UN)


def run_step(step: Step, log_file: Path) -> None:
    """Runs ``step`` until it is done, under its lock (``step_lock``): skipped when another call
    finished it while this one waited for its turn."""
    with step_lock(step, log_file.parent / ".locks", wait=step.rebuild):
        if step.is_done():
            log.info("%s: done by another call meanwhile", step.name)
            return
        _run_step(step, log_file)


def _run_step(step: Step, log_file: Path) -> None:
    """Runs ``step`` until it is done (its ``done`` file written by the command, ``after`` or here)."""
    calls = 0
    while True:
        calls += 1
        if step.command is not None:
            log.info("%s: %s", step.name, step.describe())
            with open(log_file, "a") as fh:
                fh.write(f"\n$ {step.describe()}\n")
                fh.flush()
                proc = subprocess.run(list(map(str, step.command)), stdout=fh, stderr=subprocess.STDOUT,
                                      env={**os.environ, **step.env})
            if proc.returncode != 0:
                raise StepFailed(f"step {step.name} failed (exit {proc.returncode}): {step.describe()} "
                                 f"(its output: {log_file})")
        if step.action is not None:
            log.info("%s", step.name)
            step.action()
        if step.repeat_until is None or step.repeat_until():
            break
        if calls >= step.max_calls:
            raise StepFailed(f"step {step.name}: not done after {calls} calls of {step.describe()}")
    if step.after is not None:
        step.after()
    if not step.done.exists():
        step.done.parent.mkdir(parents=True, exist_ok=True)
        step.done.write_text(f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} {step.marker_text()}\n")


def run_plan(steps: Sequence[Step], log_file: Path, *, only: Optional[Sequence[str]] = None,
             dry_run: bool = False, lanes: int = 1) -> list[str]:
    """Runs the steps not yet done, in order; returns the names of those it ran (or would run).
    ``only``: prefixes of step names to run (the others are left as they are). ``lanes``: how
    many ``lane_group``s of a block run side by side."""
    todo = [s for s in steps if not s.is_done() and (not only or any(s.name.startswith(p) for p in only))]
    how_far = {s.name: s.progress() for s in todo if s.progress is not None}  # e.g. "at step 3000 of 5000"
    begun = [f"{name} ({text})" for name, text in how_far.items() if text]
    for step in steps:
        state = "to do" if step in todo else ("done" if step.is_done() else "skipped (only=)")
        log.info("[%s] %s%s", state, step.name, f" ({how_far[step.name]})" if how_far.get(step.name) else "")
    if dry_run:
        costs = step_costs(todo)
        for step in todo:
            print(f"{step.name} [{format_cpu(costs[step.name])}]: {step.describe()}")
        if begun:
            print("begun: " + "; ".join(begun))
        print(cost_line(todo, costs))
        return [s.name for s in todo]
    log_file.parent.mkdir(parents=True, exist_ok=True)
    ran: list[str] = []
    for block in blocks(todo):
        if len(block) == 1 or lanes <= 1:
            for group in block:
                ran += run_group(group, log_file)
            continue
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(lanes) as pool:  # each lane waits on its own subprocess
            for future in [pool.submit(run_group, group, log_file) for group in block]:
                ran += future.result()
    return [s.name for s in todo if s.name in ran]


def step_costs(todo: Sequence[Step]) -> dict[str, Optional[float]]:
    """Each step's estimated CPU-seconds (``Step.cpu_s_left``; None: no estimate)."""
    return {s.name: (s.cpu_s_left() if s.cpu_s_left is not None else None) for s in todo}


def format_cpu(cpu_s: Optional[float]) -> str:
    """``~1.7 CPU-h``, ``~12 CPU-min`` or ``~8 CPU-s``; ``no estimate`` for None."""
    if cpu_s is None:
        return "no estimate"
    if cpu_s >= 3600:
        return f"~{cpu_s / 3600:.1f} CPU-h"
    return f"~{cpu_s / 60:.0f} CPU-min" if cpu_s >= 60 else f"~{cpu_s:.0f} CPU-s"


def cost_line(todo: Sequence[Step], costs: Optional[dict[str, Optional[float]]] = None) -> str:
    """The sum of the steps' estimates (every step listed), by what they do (the word before a
    step name's ``:``), and the steps with no estimate."""
    costs = step_costs(todo) if costs is None else costs
    by_kind: dict[str, float] = {}
    for name, cpu_s in costs.items():
        if cpu_s is not None:
            head, _, rest = name.partition(":")  # "stage 0: ..." -> stage 0; "table1: sweep (seeds 1)" -> sweep
            kind = (rest if head.startswith("table") and rest else head).split(" (")[0].strip()
            by_kind[kind] = by_kind.get(kind, 0.0) + cpu_s
    unknown = [name for name, cpu_s in costs.items() if cpu_s is None]
    parts = ", ".join(f"{kind} {format_cpu(cpu_s).lstrip('~')}" for kind, cpu_s in by_kind.items())
    line = (f"estimate: {format_cpu(sum(by_kind.values()))} for {len(costs) - len(unknown)} of {len(costs)} "
            f"step(s) listed" + (f" ({parts})" if parts else "") +
            "; wall time: divide by the steps' workers or lanes; rates: gspi/reproduce/costs.py, trainings' from the run log")
    return line + (f"; no estimate for {', '.join(unknown)}" if unknown else "")


def run_group(group: Sequence[Step], log_file: Path) -> list[str]:
    """Runs a group's steps in order; returns their names. A lane's group (one run's training and
    measure) that another call is running is left to it, whole, and this call goes on with the next
    group: two calls on one work folder share out the runs instead of the second one stopping."""
    ran = []
    for step in group:
        t0, cpu0 = time.perf_counter(), cpu_seconds()
        try:
            run_step(step, log_file)
        except StepBusy as exc:
            if step.lane_group is None:
                raise
            log.warning("%s; going on with the next run", exc)
            return ran
        ran.append(step.name)
        log.info("%s: done in %.0f s (%.0f CPU-s)", step.name, time.perf_counter() - t0, cpu_seconds() - cpu0)
    return ran


def cpu_seconds() -> float:
    """CPU-seconds used so far by this process and its finished children (a step's command is a
    child; with lanes, the other lane's finished commands count too)."""
    import resource

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def blocks(steps: Sequence[Step]) -> list[list[list[Step]]]:
    """Consecutive steps as blocks of groups: a step without ``lane_group`` is a block of its own;
    a run of grouped steps is one block whose groups may run side by side."""
    out: list[list[list[Step]]] = []
    for step in steps:
        if step.lane_group is None or not out or out[-1][0][0].lane_group is None:
            out.append([[step]] if step.lane_group is None else [])
            if step.lane_group is None:
                continue
        groups = out[-1]
        for group in groups:
            if group[0].lane_group == step.lane_group:
                group.append(step)
                break
        else:
            groups.append([step])
    return out
