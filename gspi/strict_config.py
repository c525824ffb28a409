"""Nested config dataclasses built strictly from plain dicts (Hydra's resolved nodes).

    cfg = dataclass_from_dict(Stage3Config, {"lr": {"pbr": 0.01}}, "stage3")

Every key is checked: an unknown key raises ``ValueError`` naming its dotted path and the keys
allowed there, so a typo in an override never silently runs the default. A field whose default
is a dataclass (``field(default_factory=...)``) is built recursively from its sub-dict.

Hand-written rather than OmegaConf structured configs (``OmegaConf.structured``) because the
stage configs are also built outside Hydra (checkpoints' stored configs, tests, notebooks) and
their ``__post_init__`` checks must run on the final values.
"""
from __future__ import annotations

from dataclasses import fields, is_dataclass
from typing import Any, Mapping, TypeVar

T = TypeVar("T")


def dataclass_from_dict(kind: type[T], values: Mapping[str, Any], where: str) -> T:
    """``kind(**values)`` with nested dataclass fields built from sub-dicts.

    Args:
        kind: a dataclass type.
        values: its keys (a subset of the fields; missing ones keep their defaults).
        where: the dotted name of this node in the run config (e.g. ``"stage3"``), for errors.

    Raises:
        ValueError: ``values`` is not a mapping, or holds a key that is not a field of ``kind``.
    """
    if not isinstance(values, Mapping):
        raise ValueError(f"{where}: expected a mapping of keys, got {type(values).__name__}")
    known = {f.name: f for f in fields(kind)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ValueError(f"unknown {where.split('.')[0]} config key(s) {[f'{where}.{k}' for k in unknown]}; "
                         f"allowed in {where}: {sorted(known)}")
    kwargs = {}
    for name, value in values.items():
        factory = known[name].default_factory
        default = factory() if callable(factory) else None
        if default is not None and is_dataclass(default):
            kwargs[name] = dataclass_from_dict(type(default), value or {}, f"{where}.{name}")
        else:
            kwargs[name] = value
    return kind(**kwargs)
