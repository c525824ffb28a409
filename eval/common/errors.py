"""Stated errors: failures whose message already says what is wrong and where (a bad key, a
bad file, ``device=cuda`` without CUDA, an unsupported glTF feature).

Every project error class derives from ``StatedError`` (beside its usual base, e.g.
``ValueError``, so callers that catch those keep working). A CLI's task function is wrapped in
``exit_on_stated_error``: a stated error prints ONE line, ``<program>: error: <message>``, on
stderr and exits with status 2, with no traceback; any other exception is a bug and keeps its
traceback. Ctrl-C prints one line saying that finished work is kept and exits 130 (the shell's
status for SIGINT). ``python -m`` tools of the product run their ``main`` under
:func:`run_command`, which gives them the same two behaviours.

Ctrl-C is a promise about time too (bounded clean-up, a second Ctrl-C, an interrupted import):
``eval.common.interrupt``, which :func:`run_command` installs.
"""
from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Callable, TypeVar

from eval.common.interrupt import EXIT_INTERRUPTED, INTERRUPTED, install_interrupt_handler, interruption_in, said

EXIT_STATED = 2
F = TypeVar("F", bound=Callable)


class StatedError(Exception):
    """An error whose message names the key or file and the problem: shown as one line."""


class MissingInputError(StatedError, FileNotFoundError):
    """An input file or folder named on the command line does not exist."""


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def print_stated_error(exc: BaseException) -> None:
    """``<program>: error: <message>`` on stderr, exit 2 (the one-line form of a stated error)."""
    print(f"{Path(sys.argv[0]).name}: error: {one_line(exc)}", file=sys.stderr)
    sys.exit(EXIT_STATED)


def exit_on_stated_error(task: F) -> F:
    """Wraps a CLI task function (under ``@hydra.main``): stated errors -> one line, exit 2."""

    @functools.wraps(task)
    def wrapped(*args, **kwargs):
        try:
            return task(*args, **kwargs)
        except StatedError as exc:
            print_stated_error(exc)
        except Exception as exc:
            if interruption_in(exc) is not None:  # a Ctrl-C a library re-raised as its own error
                raise KeyboardInterrupt from exc
            raise

    return wrapped  # type: ignore[return-value]


def print_interrupted() -> None:
    """``<program>: interrupted ...`` on stderr (one line, no traceback), exit 130."""
    print(f"{Path(sys.argv[0]).name}: {INTERRUPTED}", file=sys.stderr, flush=True)
    said()
    sys.exit(EXIT_INTERRUPTED)


def run_command(main: Callable, *args, **kwargs):
    """``main(*args, **kwargs)`` of a command (a CLI, a ``python -m`` tool): a stated error is one
    line and exit 2, Ctrl-C one line and exit 130 (in bounded time: ``eval.common.interrupt``); anything else
    keeps its traceback."""
    restore = install_interrupt_handler()
    try:
        return main(*args, **kwargs)
    except StatedError as exc:
        print_stated_error(exc)
    except KeyboardInterrupt:
        print_interrupted()
    except Exception as exc:
        if interruption_in(exc) is None:
            raise
        print_interrupted()
    finally:
        restore()
