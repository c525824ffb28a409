"""``gspi-<tool> --help`` (or ``-h``): a short usage drawn from the tool's own config file.

Hydra's own ``--help`` opens with its banner and lists every config group of ``conf/``; a user asks
what this tool takes. The usage is read from ``conf/<config name>.yaml``, the one place a tool's
keys are defined: its header's first line (``# gspi-<tool>: <purpose>``) and first example line
(``#   gspi-<tool> ...``), its top-level keys with their defaults and line comments, and the config
groups of its ``defaults`` list with the options each has. Hydra's full help stays at
``--hydra-help``; the composed config at ``--cfg job``.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Optional

HELP_FLAGS = ("--help", "-h")
KEY_LINE = re.compile(r"^([A-Za-z_][\w.]*):(?:\s*(.*?))?\s*(?:#\s?(.*))?$")  # key: value  # comment


def wants_help(argv: list[str]) -> bool:
    """The command line asks for the usage (``--help`` or ``-h`` anywhere)."""
    return any(a in HELP_FLAGS for a in argv)


FORMS = {"gspi_export_asset": "gspi-export"}  # a config of a second form of a tool: that tool's console script


def tool_name(config_name: str) -> str:
    """``gspi_export_asset`` -> ``gspi-export`` (the console script, ``FORMS``), ``gspi_points_eval`` ->
    ``gspi-points-eval``."""
    return FORMS.get(config_name, config_name.replace("_", "-"))


def header(lines: list[str], tool: str) -> tuple[Optional[str], Optional[str]]:
    """(purpose, example) from a config file's opening comment block."""
    purpose = example = None
    open_sentence = False  # the purpose goes on over the next unindented comment lines to its full stop
    for line in lines:
        if not line.startswith("#"):
            break
        text = line[1:].strip()
        if purpose is None and text.startswith(f"{tool}:"):
            purpose = text[len(tool) + 1:].strip()
            open_sentence = not purpose.endswith(".")
        elif open_sentence and not line.startswith("#  ") and text:
            purpose += " " + text
            open_sentence = not text.endswith(".")
        if example is None and line.startswith("#   ") and text.startswith(tool + " "):
            example = re.split(r"\s{2,}#", text)[0].strip()  # without its trailing comment
    if purpose and ". " in purpose:  # its first sentence
        purpose = purpose.split(". ", 1)[0] + "."
    return purpose, example


def top_level_keys(lines: list[str]) -> list[tuple[str, str, str]]:
    """(key, default, comment) of each top-level key but ``defaults`` and ``hydra``; a mapping's
    default is its sub-keys' names."""
    keys: list[tuple[str, str, str]] = []
    for i, line in enumerate(lines):
        match = KEY_LINE.match(line)
        if not match or match.group(1) in ("defaults", "hydra"):
            continue
        key, value, comment = match.group(1), (match.group(2) or "").strip(), (match.group(3) or "").strip()
        if not value:  # a mapping: its indented sub-keys
            subs = []
            for sub in lines[i + 1:]:
                if sub and not sub.startswith(" "):
                    break
                m = re.match(r"^  ([A-Za-z_]\w*):", sub)
                if m:
                    subs.append(m.group(1))
            value = "{" + ", ".join(subs) + "}"
        keys.append((key, value, comment))
    return keys


def config_groups(conf_dir: Path, lines: list[str]) -> list[tuple[str, str, list[str]]]:
    """(group, default option, every option) of the ``defaults`` list."""
    groups = []
    in_defaults = False
    for line in lines:
        if line.startswith("defaults:"):
            in_defaults = True
            continue
        if in_defaults and not line.startswith((" ", "-")):
            break
        m = re.match(r"^\s*-\s*(?:override\s+)?([\w/]+)\s*:\s*([^#\s]+)", line) if in_defaults else None
        if m and not m.group(1).startswith("hydra"):  # Hydra's own settings (job_logging, launcher)
            group = m.group(1)
            options = sorted(p.stem for p in (conf_dir / group).glob("*.yaml"))
            groups.append((group, m.group(2), options))
    return groups


def usage(conf_dir: Path | str, config_name: str, *, purpose: Optional[str] = None,
          example: Optional[str] = None, groups: bool = True, hydra: bool = True) -> str:
    """The usage of the tool whose primary config is ``conf/<config_name>.yaml`` (``groups``:
    list its config groups; ``hydra``: the tool is a Hydra app; ``purpose``/``example``: instead
    of the file header's)."""
    conf_dir = Path(conf_dir)
    tool = tool_name(config_name)
    lines = (conf_dir / f"{config_name}.yaml").read_text().splitlines()
    found_purpose, found_example = header(lines, tool)
    purpose, example = purpose or found_purpose, example or found_example
    out = [f"{tool}: {purpose}" if purpose else tool, "",
           f"usage: {tool} key=value ... ({'Hydra overrides' if hydra else 'keys'} of conf/{config_name}.yaml)",
           "", "keys (default):"]
    keys = top_level_keys(lines)
    width = max((len(k) + len(v) + 1 for k, v, _ in keys), default=0)
    for key, value, comment in keys:
        out.append((f"  {f'{key}={value}':<{width}}" + (f"  # {comment}" if comment else "")).rstrip())
    found_groups = config_groups(conf_dir, lines) if groups else []
    if found_groups:
        out += ["", "config groups (group=option; default first):"]
        for group, default, options in found_groups:
            others = [o for o in options if o != default]
            out.append(f"  {group}={default}" + (f"  (also: {', '.join(others)})" if others else ""))
    out += ["", "example:", f"  {example or tool}"]
    if hydra:
        out += ["", "??? = required. Any nested key too (group.key=value). Hydra's own help: --hydra-help; "
                    "the composed config: --cfg job"]
    return "\n".join(out)
