"""Ctrl-C, kept in bounded time: one line and exit 130, whatever the clean-up does.

``eval.common.errors.run_command`` installs :func:`on_interrupt` for SIGINT. The first Ctrl-C
raises ``KeyboardInterrupt`` as Python's own handler does and arms a watchdog: a command that has
not exited ``INTERRUPT_GRACE_S`` seconds later (its clean-up blocked: a lock left held, a thread
that will not join; a CI run once waited 240 s on a ``gspi-run`` sent SIGINT) writes where each
thread stood (faulthandler) and the one line, and exits 130 at once; a second Ctrl-C does so
without waiting. A Ctrl-C that arrives while a module of ``DEFERRED_IMPORTS`` (``torch``) is being
imported waits for the import to finish: raised inside it, the interruption crosses torch's native
initialisers, and the process aborted (SIGABRT) or died of SIGINT after the line in 2 of 36 tries
on the 2-core VM. A ``KeyboardInterrupt`` that a library re-raised as another error (Python wraps
one raised inside a class body's ``__set_name__``, as during torch's import, in a ``RuntimeError``)
is still an interruption: :func:`interruption_in`. ``GSPI_INTERRUPT_GRACE_S`` sets the grace time.
"""
from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Callable

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for Ctrl-C
INTERRUPTED = ("interrupted (Ctrl-C); finished work (jobs, scenes, checkpoints, records) is kept: "
               "run the same command again to go on")
INTERRUPT_GRACE_S = float(os.environ.get("GSPI_INTERRUPT_GRACE_S", "30"))  # clean-up time after Ctrl-C
FORCED = "did not stop within {:g} s of Ctrl-C; where each thread stood is above; stopped at once"
DEFERRED_IMPORTS = ("torch",)  # modules whose import a Ctrl-C waits for (native initialisers)
# this process's Ctrl-C so far: "armed" (the first raised, the watchdog runs), "deferred" (waiting for
# an import), "said" (the one line is written: the watchdog must not repeat it)
_state = {"armed": False, "deferred": False, "said": False}


def said() -> None:
    """Records that the one interrupted line has been written."""
    _state["said"] = True


def interruption_in(exc: BaseException) -> "KeyboardInterrupt | None":
    """The ``KeyboardInterrupt`` behind ``exc`` (itself, its cause or context, transitively)."""
    seen: set[int] = set()
    current: "BaseException | None" = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


def _stop_now(why: str, stacks: bool = False) -> None:
    """Exit 130 without clean-up: where each thread stands (``stacks``), then the one line (or,
    when it was written already, ``why`` alone)."""
    if stacks:
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    name = Path(sys.argv[0]).name
    print(f"{name}: {why}" if _state["said"] else f"{name}: {INTERRUPTED} ({why})", file=sys.stderr, flush=True)
    os._exit(EXIT_INTERRUPTED)


def importing(name: str) -> bool:
    """Whether module ``name`` is being imported now (importlib marks its spec while it runs)."""
    module = sys.modules.get(name)
    return bool(getattr(getattr(module, "__spec__", None), "_initializing", False))


def _deliver_after_imports(signum: int) -> None:
    """Sends ``signum`` to this process again once no module of DEFERRED_IMPORTS is being imported."""
    def wait() -> None:
        while any(importing(name) for name in DEFERRED_IMPORTS):
            time.sleep(0.02)
        _state["deferred"] = False
        os.kill(os.getpid(), signum)

    _state["deferred"] = True
    threading.Thread(target=wait, name="ctrl-c after import", daemon=True).start()


def on_interrupt(signum, frame) -> None:
    """SIGINT handler: the first raises ``KeyboardInterrupt`` (as Python's own; after the import
    under way of a module of DEFERRED_IMPORTS) and arms the watchdog; the next stops the process
    at once."""
    if _state["armed"] or _state["deferred"]:
        _stop_now("a second Ctrl-C: stopped at once")
    if any(importing(name) for name in DEFERRED_IMPORTS):
        _deliver_after_imports(signum)
        return
    _state["armed"] = True
    watchdog = threading.Timer(INTERRUPT_GRACE_S, _stop_now, args=(FORCED.format(INTERRUPT_GRACE_S), True))
    watchdog.daemon = True  # never what keeps the process alive
    watchdog.start()
    raise KeyboardInterrupt


def install_interrupt_handler() -> Callable[[], None]:
    """:func:`on_interrupt` for SIGINT where Python's own handler is in place (the main thread;
    not where SIGINT is ignored, e.g. a job started in the background). Returns what puts the
    previous handler back."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return lambda: None
    signal.signal(signal.SIGINT, on_interrupt)
    return lambda: signal.signal(signal.SIGINT, signal.default_int_handler)
