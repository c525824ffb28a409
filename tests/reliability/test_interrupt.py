"""Ctrl-C is one line and exit 130, within a bounded time (eval/common/interrupt.py).

A CI run once waited 240 s on a gspi-run that had been sent SIGINT; the first Ctrl-C now arms a
watchdog (``INTERRUPT_GRACE_S``) and a second stops the process at once. These tests hang the
clean-up on purpose, in a small child process, and check that it still ends as promised.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from eval.common.errors import run_command
from eval.common.interrupt import EXIT_INTERRUPTED, install_interrupt_handler, interruption_in

REPO = Path(__file__).resolve().parents[2]

# The child: run_command around a main that signals it is ready, waits for Ctrl-C, then hangs in
# its clean-up on a lock nobody will release (a KeyboardInterrupt left a lock held).
HANGING_CLEANUP = textwrap.dedent("""
    import sys, threading, time
    from eval.common.errors import run_command

    def main():
        lock = threading.Lock()
        lock.acquire()
        print("ready", flush=True)
        try:
            while True:
                time.sleep(0.05)
        finally:
            lock.acquire()  # never returns: the clean-up hangs

    run_command(main)
""")


def start_child(tmp_path: Path, script: str, ready: str, **env: str) -> tuple[subprocess.Popen, Path]:
    """``python -c script`` (SIGINT at its default, as from a terminal), once it has printed ``ready``."""
    log = tmp_path / "log.txt"
    env = {**os.environ, "PYTHONPATH": str(REPO), **env}
    fh = open(log, "w")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=fh, stderr=subprocess.STDOUT,
                            env=env, cwd=tmp_path,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while ready not in log.read_text():
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, log.read_text()
        time.sleep(0.02)
    return proc, log


def interrupted_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if "interrupted (Ctrl-C)" in line]


def test_a_hung_clean_up_is_stopped_after_the_grace_time_with_the_stacks_and_one_line(tmp_path):
    proc, log = start_child(tmp_path, HANGING_CLEANUP, "ready", GSPI_INTERRUPT_GRACE_S="2")
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=120)
    waited = time.monotonic() - sent
    text = log.read_text()
    assert code == EXIT_INTERRUPTED, text
    assert waited >= 2, f"stopped after {waited:.1f} s, before the grace time"
    lines = interrupted_lines(text)
    assert len(lines) == 1 and "did not stop within 2 s" in lines[0], text
    assert "most recent call first" in text and "lock.acquire()" not in lines[0], text  # the stacks


def test_a_second_ctrl_c_stops_at_once(tmp_path):
    proc, log = start_child(tmp_path, HANGING_CLEANUP, "ready", GSPI_INTERRUPT_GRACE_S="600")
    proc.send_signal(signal.SIGINT)
    time.sleep(1.0)
    assert proc.poll() is None, log.read_text()  # hung in its clean-up, the watchdog far off
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=60)
    text = log.read_text()
    assert code == EXIT_INTERRUPTED, text
    lines = interrupted_lines(text)
    assert len(lines) == 1 and "a second Ctrl-C" in lines[0], text


def test_a_ctrl_c_a_library_re_raised_as_its_own_error_is_an_interruption(capsys):
    """Python re-raises a KeyboardInterrupt met in a class body's __set_name__ (torch's import) as
    a RuntimeError: it must still be one line and exit 130, not a traceback and exit 1."""
    def importing():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance") from exc

    with pytest.raises(SystemExit) as exc:
        run_command(importing)
    assert exc.value.code == EXIT_INTERRUPTED
    assert len(interrupted_lines(capsys.readouterr().err)) == 1

    def broken():
        raise RuntimeError("a bug, not an interruption")

    with pytest.raises(RuntimeError, match="a bug"):
        run_command(broken)


def test_interruption_in_follows_causes_and_contexts_and_stops_on_a_cycle():
    root = KeyboardInterrupt()
    middle = ValueError("middle")
    middle.__context__ = root
    top = RuntimeError("top")
    top.__cause__ = middle
    assert interruption_in(top) is root
    a, b = ValueError("a"), ValueError("b")
    a.__context__, b.__context__ = b, a
    assert interruption_in(a) is None


def test_the_handler_leaves_an_ignored_sigint_ignored_and_is_put_back():
    previous = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a job started in the background
        install_interrupt_handler()()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        signal.signal(signal.SIGINT, signal.default_int_handler)
        restore = install_interrupt_handler()
        assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        restore()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)


# The child imports a module that stands in for torch (a long import whose native initialisers a
# KeyboardInterrupt must not cross): Ctrl-C during it waits for the import, then stops the command.
SLOW_IMPORT = textwrap.dedent("""
    import time
    print("importing", flush=True)
    try:
        for _ in range(30):
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("interrupted inside the import", flush=True)
        raise
    print("imported", flush=True)
""")
IMPORTING_MAIN = textwrap.dedent("""
    import time
    from eval.common import errors, interrupt

    interrupt.DEFERRED_IMPORTS = ("slow_native",)

    def main():
        import slow_native
        while True:
            time.sleep(0.05)

    errors.run_command(main)
""")


def test_a_ctrl_c_during_a_deferred_import_waits_for_it_then_stops_the_command(tmp_path):
    (tmp_path / "slow_native.py").write_text(SLOW_IMPORT)
    proc, log = start_child(tmp_path, IMPORTING_MAIN, "importing",
                            PYTHONPATH=os.pathsep.join([str(REPO), str(tmp_path)]))
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=60)
    text = log.read_text()
    assert code == EXIT_INTERRUPTED, text
    assert "imported" in text and "interrupted inside the import" not in text, text
    assert len(interrupted_lines(text)) == 1 and "Traceback" not in text, text
