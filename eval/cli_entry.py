"""The one way a gspi CLI starts: one config directory (``eval.config.CONF_DIR``), its argv
aliases rewritten by the one table ``eval.argv.ALIASES``, its path keys quoted for Hydra's grammar (``eval.argv``), the command line checked
against the config before Hydra starts (``eval.cli_precheck``: missing required keys, bad
overrides), its task run under ``@hydra.main`` with stated errors as one line and Ctrl-C as one line with exit
130 (``eval.errors``); ``--help``/``-h`` prints the tool's own usage (``eval.cli_help``).

    main = hydra_cli(run_task, "gspi_extract", path_keys=("asset", "out", "scene"))
"""
from __future__ import annotations

import sys
from typing import Callable, Optional

from eval.argv import apply_aliases, quote_path_overrides
from eval.cli_help import usage, wants_help
from eval.config import CONF_DIR
from eval.errors import exit_on_stated_error, print_stated_error, run_command


def hydra_cli(task: Callable, config_name: str, *, path_keys: tuple[str, ...] = (),
              rewrite: Optional[Callable[[list[str]], list[str]]] = None) -> Callable[[], None]:
    """The console-script ``main()`` of a CLI whose Hydra task is ``task(cfg)``."""
    import hydra

    hydra_main = hydra.main(version_base="1.3", config_path=CONF_DIR, config_name=config_name)(
        exit_on_stated_error(task))

    def start() -> None:
        if wants_help(sys.argv[1:]):  # the tool's own keys, not Hydra's banner (eval/cli_help.py)
            print(usage(CONF_DIR, config_name))
            return
        argv = apply_aliases(sys.argv[1:], config_name)  # the one alias table (eval.argv.ALIASES)
        argv = argv if rewrite is None else rewrite(argv)
        argv = quote_path_overrides(argv, path_keys)
        precheck_or_exit(config_name, argv)
        sys.argv = [sys.argv[0], *argv]
        hydra_main()

    def main() -> None:
        run_command(start)  # Ctrl-C anywhere (Hydra's start-up, a job, a sweep): one line, exit 130

    main.__doc__ = f"{config_name.replace('_', '-')}: see conf/{config_name}.yaml"
    return main


def precheck_or_exit(config_name: str, argv: list[str]) -> None:
    """:func:`eval.cli_precheck.precheck`: a missing required key or a bad override -> one line, exit 2."""
    from eval.cli_precheck import CommandLineError, precheck

    try:
        precheck(CONF_DIR, config_name, argv)
    except CommandLineError as exc:
        print_stated_error(exc)
