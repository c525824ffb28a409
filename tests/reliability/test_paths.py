"""Class 9, paths that needed undocumented quoting: `=`, `,`, `'`, spaces and non-ASCII in a
path, including the `method=gspi` job folders our own sweeps write. The CLIs quote their path
keys for Hydra (eval/common/argv.py) and gspi-table quotes its positional folders."""
from __future__ import annotations

import shutil

import pytest

from tests.reliability.helpers import EVAL_FAST, run_cli

AWKWARD = ["method=gspi", "it's", "a,b", "ünï cödé", "x=1,y='2'"]


@pytest.mark.parametrize("folder", AWKWARD)
def test_gspi_eval_then_gspi_table_accept_any_folder_name(workspace, folder):
    from eval.cli import main
    from eval.tables.cli import main as table_main

    root = workspace / "runs" / folder
    shutil.move(str(workspace / "pred"), str(root / "predictions"))
    out = root / "eval"
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={root / 'predictions'}", f"out={out}", *EVAL_FAST])
    assert code == 0 and (out / "summary.json").is_file(), text[-2000:]
    code, text = run_cli(table_main, [str(out), f"out={root / 'tables'}"])
    assert code == 0 and (root / "tables" / "table1.md").is_file(), text[-2000:]


def test_quoting_round_trips_through_hydras_parser():
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from eval.common.argv import quote_path_overrides

    parser = OverridesParser.create()
    for value in [*AWKWARD, "trailing\\", "plain/path", "${oc.env:HOME}/x"]:
        arg = quote_path_overrides([f"pred={value}"], ("pred",))[0]
        assert parser.parse_override(arg).value() == value, arg
    # other keys keep their syntax (lists, numbers)
    assert quote_path_overrides(["eval.channels=[albedo]", "seed=1"], ("pred",)) == ["eval.channels=[albedo]", "seed=1"]
