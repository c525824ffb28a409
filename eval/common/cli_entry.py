"""The one way a gspi CLI starts: one config directory (``eval.common.conf.CONF_DIR``), its argv
aliases rewritten by the one table ``eval.common.argv.ALIASES``, its path keys quoted for Hydra's grammar (``eval.common.argv``), the command line checked
against the config before Hydra starts (``eval.common.cli_precheck``: missing required keys, bad
overrides), its task run under ``@hydra.main`` with stated errors as one line and Ctrl-C as one line with exit
130 (``eval.common.errors``); ``--help``/``-h`` prints the tool's own usage (``eval.common.cli_help``).

    main = hydra_cli(run_task, "gspi_extract", path_keys=("asset", "out", "scene"))
"""
from __future__ import annotations

import functools
import sys
from pathlib import Path
from typing import Callable, Optional

from eval.common.argv import apply_aliases, quote_path_overrides
from eval.common.cli_help import usage, wants_help
from eval.common.conf import CONF_DIR
from eval.common.errors import StatedError, exit_on_stated_error, print_stated_error, run_command


def hydra_cli(task: Callable, config_name: str, *, path_keys: tuple[str, ...] = (),
              rewrite: Optional[Callable[[list[str]], list[str]]] = None,
              check: Optional[Callable[[list[str]], None]] = None) -> Callable[[], None]:
    """The console-script ``main()`` of a CLI whose Hydra task is ``task(cfg)``. ``check(argv)``,
    when given, runs after the precheck and before Hydra starts (a stated error: one line, exit 2):
    a CLI's own check of the whole command line, e.g. every job of a sweep."""
    import hydra

    new_out: list[Path] = []  # `out` when it did not exist before this command (set by start)

    @functools.wraps(task)  # Hydra names the job (its .log) after the task's module
    def guarded(cfg):
        try:
            return task(cfg)
        except StatedError:
            remove_hydra_leftovers(*new_out)
            raise

    hydra_main = hydra.main(version_base="1.3", config_path=CONF_DIR, config_name=config_name)(
        exit_on_stated_error(guarded))

    def start() -> None:
        if wants_help(sys.argv[1:]):  # the tool's own keys, not Hydra's banner (eval/common/cli_help.py)
            print(usage(CONF_DIR, config_name))
            return
        argv = apply_aliases(sys.argv[1:], config_name)  # the one alias table (eval.common.argv.ALIASES)
        argv = argv if rewrite is None else rewrite(argv)
        argv = quote_path_overrides(argv, path_keys)
        precheck_or_exit(config_name, argv)
        out = out_override(argv)
        new_out[:] = [out, first_missing(out)] if out is not None and not out.exists() else []
        if check is not None:
            try:
                check(argv)
            except StatedError as exc:
                print_stated_error(exc)
        sys.argv = [sys.argv[0], *argv]
        hydra_main()

    def main() -> None:
        run_command(start)  # Ctrl-C anywhere (Hydra's start-up, a job, a sweep): one line, exit 130

    main.__doc__ = f"{config_name.replace('_', '-')}: see conf/{config_name}.yaml"
    return main


def precheck_or_exit(config_name: str, argv: list[str]) -> None:
    """:func:`eval.common.cli_precheck.precheck`: a missing required key or a bad override -> one line, exit 2."""
    from eval.common.cli_precheck import CommandLineError, precheck

    try:
        precheck(CONF_DIR, config_name, argv)
    except CommandLineError as exc:
        print_stated_error(exc)


def out_override(argv: list[str]) -> Optional[Path]:
    """The ``out=`` of a single run's command line (Hydra's grammar, quotes removed); None for a
    sweep (-m) or when absent."""
    if any(a in ("-m", "--multirun") for a in argv):
        return None
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        parsed = OverridesParser.create().parse_overrides([a for a in argv if not a.startswith("-")])
    except Exception:  # the precheck has already refused a malformed line; nothing to clean then
        return None
    for override in parsed:
        if override.key_or_group == "out" and not override.is_sweep_override():
            value = override.value()
            return Path(str(value)) if value not in (None, "") else None
    return None


def first_missing(path: Path) -> Path:
    """The outermost folder of ``path`` that does not exist yet (what creating it makes)."""
    path = path.absolute()
    top = path
    for parent in path.parents:
        if parent.exists():
            break
        top = parent
    return top


def remove_hydra_leftovers(out: Optional[Path] = None, created: Optional[Path] = None) -> None:
    """After a stated error, removes the ``out`` folder this command created when it holds only
    what Hydra put there before the task ran (``.hydra/`` and the job's ``.log``), and the empty
    parents it made up to ``created``: a refused command leaves no folder behind. A folder that existed before, or that holds anything of the
    task, is left as it is."""
    import shutil

    from hydra.core.hydra_config import HydraConfig

    if out is None or not out.is_dir():
        return
    try:
        hydra_cfg = HydraConfig.get()
        if Path(hydra_cfg.runtime.output_dir).resolve() != out.resolve():
            return
        log_name = f"{hydra_cfg.job.name}.log"
    except ValueError:  # no Hydra config: not under @hydra.main
        return
    ours = {".hydra", log_name}
    if not all(p.name in ours for p in out.iterdir()):
        return
    shutil.rmtree(out / ".hydra", ignore_errors=True)
    (out / log_name).unlink(missing_ok=True)
    folder = out.absolute()
    created = (created or out).absolute()
    while True:  # the folder, and the empty parents this command made for it
        try:
            folder.rmdir()
        except OSError:
            return
        if folder == created or created not in folder.parents:
            return
        folder = folder.parent
