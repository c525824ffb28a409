"""The one validation layer of config values: names, types and ranges, at start-up.

    cfg = dataclass_from_dict(Stage3Config, {"lr": {"pbr": 0.01}}, "stage3")
    check_value("threads", cfg["threads"], int, lo=1)

Every key is checked: an unknown key raises ``ValueError`` naming its dotted path and the keys
allowed there, so a typo in an override never silently runs the default. Every value is checked
against its field's type annotation (``int`` refuses ``"abc"``, ``2.5`` and ``True``; ``float``
refuses strings, booleans, NaN and infinities; ``Optional[...]`` allows null) and against the
range a config class declares in ``RANGES = {"field": (lo, hi)}`` (inclusive, None = open), or a
set of allowed values in ``CHOICES``. Errors name the key, the value and what is allowed. A
field whose default is a dataclass (``field(default_factory=...)``) is built recursively.

Hand-written rather than OmegaConf structured configs (``OmegaConf.structured``) because the
stage configs are also built outside Hydra (checkpoints' stored configs, tests, notebooks) and
their ``__post_init__`` checks must run on the final values.
"""
from __future__ import annotations

import math
import typing
from dataclasses import fields, is_dataclass
from typing import Any, Mapping, Optional, TypeVar

from eval.common.errors import StatedError

T = TypeVar("T")
_NAMES = {int: "an integer", float: "a number", bool: "true or false", str: "a string"}



class ConfigError(StatedError, ValueError):
    """A config value or key that is not allowed (the message names the dotted key)."""

def _range_text(lo, hi) -> str:
    if lo is not None and hi is not None:
        return f" in [{lo}, {hi}]"
    if lo is not None:
        return f" >= {lo}"
    return f" <= {hi}" if hi is not None else ""


def check_value(key: str, value: Any, kind: type, *, lo: Optional[float] = None, hi: Optional[float] = None,
                choices: Optional[tuple] = None, optional: bool = False) -> Any:
    """``value`` if it is a ``kind`` (int, float, bool or str) within ``[lo, hi]`` / ``choices``.

    Raises:
        ValueError: ``<key>=<value>: must be <what is allowed>``.
    """
    if value is None and optional:
        return value
    allowed = _NAMES.get(kind, kind.__name__) + _range_text(lo, hi)
    if choices is not None:
        allowed = f"one of {list(choices)}"
    if optional:
        allowed += " or null"
    ok = {int: isinstance(value, int) and not isinstance(value, bool),
          float: isinstance(value, (int, float)) and not isinstance(value, bool)
          and math.isfinite(float(value)),
          bool: isinstance(value, bool), str: isinstance(value, str)}.get(kind, isinstance(value, kind))
    if ok and choices is not None:
        ok = value in choices
    if ok and lo is not None and value < lo or ok and hi is not None and value > hi:
        ok = False
    if not ok:
        raise ConfigError(f"{key}={value!r}: must be {allowed}")
    return value


def _check_field(where: str, value: Any, annotation: Any, rng: Optional[tuple], choices: Optional[tuple]) -> None:
    args = typing.get_args(annotation)
    optional = typing.get_origin(annotation) is typing.Union and type(None) in args
    if optional:
        rest = [a for a in args if a is not type(None)]
        annotation = rest[0] if len(rest) == 1 else Any
    if annotation in _NAMES:
        lo, hi = rng or (None, None)
        check_value(where, value, annotation, lo=lo, hi=hi, choices=choices, optional=optional)


def dataclass_from_dict(kind: type[T], values: Mapping[str, Any], where: str) -> T:
    """``kind(**values)`` with nested dataclass fields built from sub-dicts, every value checked.

    Args:
        kind: a dataclass type (optionally with ``RANGES`` / ``CHOICES`` class attributes).
        values: its keys (a subset of the fields; missing ones keep their defaults).
        where: the dotted name of this node in the run config (e.g. ``"stage3"``), for errors.

    Raises:
        ValueError: ``values`` is not a mapping, holds a key that is not a field of ``kind``, or
            a value of the wrong type or out of range (the message names the dotted key).
    """
    if not isinstance(values, Mapping):
        raise ConfigError(f"{where}: expected a mapping of keys, got {type(values).__name__}")
    known = {f.name: f for f in fields(kind)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(f"unknown {where.split('.')[0]} config key(s) {[f'{where}.{k}' for k in unknown]}; "
                         f"allowed in {where}: {sorted(known)}")
    hints = typing.get_type_hints(kind)
    ranges, choices = getattr(kind, "RANGES", {}), getattr(kind, "CHOICES", {})
    kwargs = {}
    for name, value in values.items():
        factory = known[name].default_factory
        default = factory() if callable(factory) else None
        if default is not None and is_dataclass(default):
            kwargs[name] = dataclass_from_dict(type(default), value or {}, f"{where}.{name}")
        else:
            _check_field(f"{where}.{name}", value, hints.get(name, Any), ranges.get(name), choices.get(name))
            kwargs[name] = value
    return kind(**kwargs)
