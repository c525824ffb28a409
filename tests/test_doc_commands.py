"""Every command that README.md, docs/COMMANDS.md and docs/REPRODUCE.md show runs as written
(issue 54).

Fast (default): each documented ``gspi-*`` command goes through its CLI's own ``main()`` (argv
aliases, positional folders, path quoting, the GLB-export dispatch) up to the start-up check that
every CLI runs before Hydra starts (``eval.common.cli_precheck``: the config composes, every group choice
of a sweep exists, no required key is left unset); the task itself is not run. Placeholders
(``<scene>``, ``...``) are filled with a dummy name. Slow: the cheap commands of REPRODUCE.md's
"tiny" section run for real, in order, in a scratch folder.
"""
from __future__ import annotations

import re
import shlex
import tomllib
from importlib import import_module
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("README.md", "docs/COMMANDS.md", "docs/REPRODUCE.md")
FENCE = re.compile(r"```[a-z]*\n(.*?)```", re.S)


def documented_commands(doc: str) -> list[str]:
    """The ``gspi-*`` command lines of ``doc``'s fenced code blocks (continuations joined)."""
    found = []
    for block in FENCE.findall((ROOT / doc).read_text()):
        for line in block.replace("\\\n", " ").splitlines():
            if re.match(r"\s*gspi-[\w-]+\s", line):  # gspi-points-eval too
                found.append(line.strip())
    return found


def console_scripts() -> dict[str, str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def filled_argv(line: str) -> list[str]:
    """``line``'s arguments with its comment dropped and placeholders filled: ``<x y>`` -> ``x_y``,
    an optional ``[...]`` dropped, a bare ``...`` argument dropped, ``key=...`` -> ``key=x``."""
    line = re.sub(r"\[<[^\]]*\]", "", line)  # gspi-table <dir> [<dir> ...]
    line = re.sub(r"<([^<>]+)>", lambda m: re.sub(r"\W+", "_", m.group(1)), line)
    argv = shlex.split(line, comments=True)[1:]
    argv = [a.replace("=...", "=x") for a in argv if a != "..."]
    return argv


ALL = [(doc, line) for doc in DOCS for line in documented_commands(doc)]


class PrecheckPassed(Exception):
    """Raised in place of starting Hydra once the start-up check has passed."""


def test_the_docs_show_commands():
    counts = {doc: len(documented_commands(doc)) for doc in DOCS}
    assert counts["README.md"] >= 15 and counts["docs/REPRODUCE.md"] >= 10, counts
    assert filled_argv("gspi-table <eval dir> [<eval dir> ...] out=<dir>  # x") == ["eval_dir", "out=dir"]
    assert filled_argv("gspi-eval gt=... pred=... out=... eval.x=y") == ["gt=x", "pred=x", "out=x", "eval.x=y"]


@pytest.mark.parametrize("doc,line", ALL, ids=[f"{d}:{i}" for i, (d, _) in enumerate(ALL)])
def test_documented_command_passes_its_cli_start_up_check(doc, line, monkeypatch, tmp_path):
    import eval.common.cli_entry as cli_entry
    from eval.common.cli_precheck import precheck
    from eval.common.conf import CONF_DIR
    from tests.reliability.helpers import run_cli

    program = line.split()[0]
    if program == "gspi-reproduce":  # no Hydra app: its start-up check is the plan (dry_run), nothing runs
        from gspi.cli.reproduce import main as reproduce_main

        argv = [a for a in filled_argv(line) if not a.startswith("dry_run=")]
        assert reproduce_main([*argv, f"data_root={tmp_path}", "dry_run=true"]) == 0, line
        return
    scripts = console_scripts()
    assert program in scripts, f"{doc}: {program} is not a console script of pyproject.toml"
    module, _, name = scripts[program].partition(":")
    main = getattr(import_module(module), name)

    def check_then_stop(config_name: str, argv: list[str]) -> None:
        precheck(CONF_DIR, config_name, argv)
        raise PrecheckPassed

    monkeypatch.setattr(cli_entry, "precheck_or_exit", check_then_stop)
    monkeypatch.chdir(tmp_path)  # a folder named in the line must not exist by accident
    from eval.config import register_configs

    register_configs()  # what gspi-run's and gspi-eval's main() do before Hydra
    try:
        code, text = run_cli(main, filled_argv(line))
    except PrecheckPassed:
        return
    pytest.fail(f"{doc}: `{line}` did not pass its start-up check (exit {code}):\n{text[-1500:]}")


TINY = "recon=tiny stage1=tiny stage1.image_size=64 stage2=tiny stage3=tiny logger=none"


@pytest.mark.slow
def test_reproduce_tiny_section_runs_as_written(tmp_path, monkeypatch):
    """REPRODUCE.md's tiny commands, for real (minutes): data, the Table 3 sweep, the tables."""
    from tests.reliability.helpers import run_cli

    lines = [line for line in documented_commands("docs/REPRODUCE.md")
             if "data/tiny" in line or line.startswith("gspi-table /tmp/t2")]
    data_line = next(line for line in lines if line.startswith("gspi-data"))
    t3_line = next(line for line in lines if "+experiment=table3" in line)
    assert TINY in t3_line, "REPRODUCE.md's tiny sweep changed: update this test's command"
    monkeypatch.chdir(tmp_path)
    scripts = console_scripts()
    for line in (data_line, t3_line.replace("/tmp/t3", str(tmp_path / "t3")),
                 f"gspi-table {tmp_path / 't3'} out={tmp_path / 'tables'}"):
        module, _, name = scripts[line.split()[0]].partition(":")
        code, text = run_cli(getattr(import_module(module), name), filled_argv(line))
        assert code == 0, f"`{line}` exit {code}:\n{text[-2000:]}"
    assert (tmp_path / "tables" / "table3.md").is_file()
