"""The run record `result.json` (docs/TABLES.md, "Run record"): its one schema.

`gspi-run` writes it (gspi/run/record.py) and `gspi-table` reads it (eval/sweep.py); both build
and check it here, so the writer can never produce a record the reader refuses. Lives in
``eval/`` because the evaluator imports nothing from ``gspi/``.

The protocol (docs/RELIABILITY.md): a job removes its folder's record before it overwrites
anything there, and writes the new one LAST, atomically; so a record with ``status ==
"complete"`` describes exactly the files beside it, and a folder with ``.hydra/`` and no record
is a killed job that nothing tabulates or skips.
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

from eval.common.errors import StatedError
from eval.common.layout import read_json_object

RECORD_NAME = "result.json"
RECORD_FORMAT = "gspi-run"
RECORD_VERSION = 1
STATUSES = ("complete", "failed")
TABLES = ("table1", "table2", "table3")
REQUIRED_KEYS = ("format", "format_version", "status", "method", "ablation", "seed", "config_hash")


class RecordError(StatedError, ValueError):
    """A `result.json` does not follow the schema; the message names the file and the key."""


def build_record(*, status: str, cfg_hash: str, method: str, ablation: str, table: Optional[str],
                 seed: int, data: str, scenes: list[str], error: Optional[str] = None,
                 material_eval: Optional[str] = None, points_eval: Optional[str] = None,
                 extra: Optional[dict] = None) -> dict:
    """The record's JSON object, checked against the schema (:func:`check_record`)."""
    record = {"format": RECORD_FORMAT, "format_version": RECORD_VERSION, "status": status,
              "error": error, "method": method, "ablation": ablation, "table": table,
              "seed": seed, "config_hash": cfg_hash, "data": data, "scenes": list(scenes),
              "material_eval": material_eval, "points_eval": points_eval, **(extra or {})}
    check_record(record, Path(RECORD_NAME))
    return record


def load_record_json(path: Path) -> dict:
    """The parsed JSON object of ``path``; RecordError (naming the file) if it is not one."""
    return read_json_object(path, error=RecordError, what="run record")


def check_record(data: dict, path: Path) -> None:
    """Raises RecordError naming ``path`` and the key when ``data`` breaks the schema."""
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise RecordError(f"{path}: missing key(s) {missing}")
    if data["format"] != RECORD_FORMAT or data["format_version"] != RECORD_VERSION:
        raise RecordError(f"{path}: unknown record format {data['format']!r} version "
                          f"{data['format_version']!r} (this reader knows {RECORD_FORMAT!r} "
                          f"version {RECORD_VERSION})")
    if data["status"] not in STATUSES:
        raise RecordError(f"{path}: status must be one of {STATUSES}, got {data['status']!r}")
    if data.get("table") is not None and data["table"] not in TABLES:
        raise RecordError(f"{path}: table must be one of {TABLES} or null, got {data['table']!r}")
    if not isinstance(data["seed"], int) or isinstance(data["seed"], bool):
        raise RecordError(f"{path}: seed must be an integer, got {data['seed']!r}")
    for key in ("method", "config_hash"):
        if not isinstance(data[key], str) or not data[key]:
            raise RecordError(f"{path}: {key} must be a non-empty string, got {data[key]!r}")
    for key in ("material_eval", "points_eval"):
        name = data.get(key)
        if name is not None and (not isinstance(name, str) or not name or Path(name).is_absolute()
                                 or ".." in Path(name).parts):
            raise RecordError(f"{path}: {key} must be a sub-folder name or null, got {name!r}")
    scenes = data.get("scenes")
    if scenes is not None and not (isinstance(scenes, list) and all(isinstance(s, str) for s in scenes)):
        raise RecordError(f"{path}: scenes must be a list of scene names, got {scenes!r}")


def read_record_json(run_dir: Path) -> dict:
    """``<run_dir>/result.json``, parsed and checked (RecordError otherwise)."""
    path = Path(run_dir) / RECORD_NAME
    data = load_record_json(path)
    check_record(data, path)
    return data


def invalidate_record(run_dir: Path) -> Optional[dict]:
    """Removes ``<run_dir>/result.json`` (before a job overwrites anything of the folder);
    returns the removed record (None if there was none or it was unreadable)."""
    path = Path(run_dir) / RECORD_NAME
    try:
        old = read_record_json(run_dir)
    except RecordError:
        old = None
    path.unlink(missing_ok=True)
    return old
