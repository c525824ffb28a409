"""Paths on the command line: quoted for Hydra's override grammar, so any folder name works.

    gspi-eval gt=data/small pred=runs/method=gspi/predictions out=runs/e   # our own sweep folders
    gspi-eval gt=data/small "pred=runs/ünï code's,x/predictions" out=/tmp/e

Hydra reads ``key=value`` with a grammar in which ``=``, ``,``, ``'``, spaces, ``~`` and
non-ASCII letters end or break an unquoted value. Every CLI passes its argv through
:func:`quote_path_overrides` with the keys that hold paths, which wraps such a value in Hydra's
single quotes (escaping ``'`` and trailing backslashes); values already quoted, or only made of
safe characters, are left as given. Only path keys are touched, so ``eval.channels=[albedo]``
keeps its list syntax.
"""
from __future__ import annotations

import re

SAFE_VALUE = re.compile(r"[A-Za-z0-9_/\-+.$%*@?|:{}]*")  # Hydra's unquoted-value characters


def quote_value(value: str) -> str:
    """``value`` as one quoted Hydra string (the parser gives back exactly ``value``)."""
    escaped = re.sub(r"(\\+)(?='|$)", lambda m: m.group(1) * 2, value)
    return "'" + escaped.replace("'", "\\'") + "'"


def needs_quoting(value: str) -> bool:
    return not (value[:1] in ("'", '"') and value[-1:] == value[:1] and len(value) > 1) \
        and not SAFE_VALUE.fullmatch(value)


def quote_path_overrides(argv: list[str], keys: tuple[str, ...]) -> list[str]:
    """``key=value`` -> ``key='value'`` for ``key`` in ``keys`` (optionally ``+``/``++`` prefixed)
    when ``value`` holds characters Hydra's grammar does not accept unquoted."""
    out = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        if sep and key.lstrip("+") in keys and needs_quoting(value):
            arg = f"{key}={quote_value(value)}"
        out.append(arg)
    return out


# The command line's aliases, one table for every CLI (issue 40): config name -> {alias: key}.
# `gspi-run data=DIR` is `data_dir=DIR` (`data` is a config group there), `gspi-data preset=tiny`
# the group choice `data=tiny`, `gspi-eval method=X` the key `method_name=X` (`method` is a
# group), `gspi-export/-import system=X` the group `method=X`.
ALIASES: dict[str, dict[str, str]] = {
    "gspi_run": {"data": "data_dir"},
    "gspi_train": {"data": "data_dir"},
    "gspi_points_eval": {"data": "data_dir"},
    "gspi_data": {"preset": "data", "+preset": "data"},
    "gspi_eval": {"method": "method_name"},
    "gspi_export": {"system": "method"},
    "gspi_import": {"system": "method"},
}


def apply_aliases(argv: list[str], config_name: str) -> list[str]:
    """``alias=value`` -> ``key=value`` by ``ALIASES[config_name]`` (other arguments unchanged)."""
    table = ALIASES.get(config_name, {})
    out = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        out.append(f"{table[key]}={value}" if sep and key in table else arg)
    return out
