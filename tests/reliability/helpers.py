"""Running a CLI as a user does (argv in, exit status and text out), in-process for speed, and
checking the promises of docs/RELIABILITY.md: exit status, the message names the file or key,
nothing written outside ``out``, no earlier result lost or misreported."""
from __future__ import annotations

import contextlib
import io
import os
import re
import sys
from pathlib import Path
from typing import Callable, Iterable

# gspi-eval without relighting or progress bars: about a second on the 32-px sphere scene
EVAL_FAST = ["progress=false", "eval.channels=[roughness,metallic]"]


def run_cli(main: Callable[[], None], argv: Iterable[str]) -> tuple[int, str]:
    """(exit status, stdout + stderr) of ``main()`` with ``sys.argv = [prog, *argv]``.

    Hydra's ``@hydra.main`` reports an exception as a message and ``sys.exit(1)``, as it does
    on the command line (HYDRA_FULL_ERROR unset)."""
    old_argv, old_env = sys.argv, os.environ.pop("HYDRA_FULL_ERROR", None)
    out, err = io.StringIO(), io.StringIO()
    sys.argv = ["gspi-cli", *map(str, argv)]
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        from hydra.core.global_hydra import GlobalHydra

        GlobalHydra.instance().clear()  # an interrupted run (a simulated kill) leaves it set
        sys.argv = old_argv
        if old_env is not None:
            os.environ["HYDRA_FULL_ERROR"] = old_env
    return code, out.getvalue() + err.getvalue()


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    """Every file below ``root``: relative path -> (size, mtime_ns)."""
    root = Path(root)
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in root.rglob("*") if p.is_file() and not p.is_symlink()}


def changed(before: dict, after: dict) -> set[str]:
    """Paths added, removed or modified between two snapshots."""
    return {k for k in set(before) | set(after) if before.get(k) != after.get(k)}


def assert_written_only_under(before: dict, after: dict, *allowed: str) -> None:
    """Every change between the snapshots lies under one of the ``allowed`` relative folders."""
    outside = sorted(p for p in changed(before, after)
                     if not any(p == a or p.startswith(a.rstrip("/") + "/") for a in allowed))
    assert not outside, f"written outside {allowed}: {outside[:10]}"


ERROR_LINE = re.compile(r"^(?:[\w.]+(?:Error|Exception)|AssetError|KeyError): (.*)$", re.MULTILINE)


def error_message(text: str) -> str:
    """The message of the error a CLI reported: the last ``SomeError: message`` line (Hydra
    prints the task's traceback above it), else the last non-empty line."""
    found = ERROR_LINE.findall(text)
    lines = [line for line in text.splitlines() if line.strip()]
    return found[-1] if found else (lines[-1] if lines else "")


def assert_fails_naming(code: int, text: str, *names: str) -> None:
    """A refusal: non-zero exit, and every one of ``names`` in the error's own message (not
    merely somewhere in a traceback or in the echoed overrides)."""
    assert code != 0, f"exit 0 for a bad input:\n{text[-2000:]}"
    message = error_message(text)
    missing = [n for n in names if n not in message]
    assert not missing, f"message does not name {missing}: {message!r}\n{text[-2000:]}"
