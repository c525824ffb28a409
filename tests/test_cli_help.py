"""``--help`` of every console script (eval/common/cli_help.py, issue 68): the tool's purpose, its own keys
with their defaults, its config groups and one example, not Hydra's banner; exit 0."""
from __future__ import annotations

import importlib
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

from eval.common.cli_help import config_groups, header, top_level_keys, usage

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


def config_keys(program: str) -> list[str]:
    """The top-level keys of the tool's primary config (conf/gspi_<tool>.yaml)."""
    cfg = yaml.safe_load((ROOT / "conf" / f"{program.replace('-', '_')}.yaml").read_text())
    return [k for k in cfg if k not in ("defaults", "hydra")]


def help_text(program: str, flag: str, monkeypatch, capsys) -> str:
    """``<program> <flag>`` in-process through its console-script entry; asserts exit 0."""
    module, _, name = SCRIPTS[program].partition(":")
    monkeypatch.setattr(sys, "argv", [program, flag])
    try:
        getattr(importlib.import_module(module), name)()
    except SystemExit as exc:
        assert exc.code in (None, 0), f"{program} {flag}: exit {exc.code}"
    return capsys.readouterr().out


@pytest.mark.parametrize("program", sorted(SCRIPTS))
def test_help_shows_the_tools_own_keys_and_an_example(program, monkeypatch, capsys):
    out = help_text(program, "--help", monkeypatch, capsys)
    assert out.startswith(f"{program}: ") and len(out.splitlines()[0]) > len(program) + 10  # its purpose
    for key in config_keys(program):
        assert f"\n  {key}=" in out, f"{program} --help lacks its key {key}"
    assert "\nexample:\n  " + program + " " in out
    assert "Powered by Hydra" not in out and "== Config ==" not in out
    assert help_text(program, "-h", monkeypatch, capsys) == out


def test_help_exits_0_from_the_installed_script():
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([str(BIN / "gspi-eval"), "--help"], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("gspi-eval: score a prediction folder") and "gt=???" in proc.stdout
    assert "eval=default  (also: " in proc.stdout and "stanford_orb" in proc.stdout


def test_the_export_asset_form_has_its_own_help(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["gspi-export", "asset=x.ply", "--help"])
    importlib.import_module("gspi.cli.export").main()
    out = capsys.readouterr().out
    assert "conf/gspi_export_asset.yaml" in out and "\n  export={mesh, texture, preview, backend}" in out


def test_usage_reads_defaults_comments_groups_and_the_header(tmp_path):
    (tmp_path / "color").mkdir()
    for option in ("red", "blue"):
        (tmp_path / "color" / f"{option}.yaml").write_text("x: 1\n")
    lines = ["# gspi-demo: paint things. More words here.", "#   gspi-demo out=/tmp/x   # a comment",
             "defaults:", "  - _self_", "  - color: red", "  - override hydra/job_logging: stdout", "",
             "out: ???   # where it goes", "size: 4", "nested:   # a mapping", "  a: 1", "  b: 2",
             "hydra:", "  run:", "    dir: ${out}"]
    (tmp_path / "gspi_demo.yaml").write_text("\n".join(lines) + "\n")
    assert header(lines, "gspi-demo") == ("paint things.", "gspi-demo out=/tmp/x")
    assert top_level_keys(lines) == [("out", "???", "where it goes"), ("size", "4", ""),
                                     ("nested", "{a, b}", "a mapping")]
    assert config_groups(tmp_path, lines) == [("color", "red", ["blue", "red"])]
    text = usage(tmp_path, "gspi_demo")
    assert text.splitlines()[0] == "gspi-demo: paint things."
    assert "  color=red  (also: blue)" in text and "example:\n  gspi-demo out=/tmp/x" in text
