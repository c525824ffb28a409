"""The run record `result.json` of a `gspi-run` job: the config hash, and reading/writing it.

The schema is defined once, in ``eval/records/run_record.py`` (gspi-table reads it there too). The
protocol: :func:`invalidate_result` removes the folder's record before a job overwrites anything,
:func:`write_result` writes the new one LAST and atomically, so a record with ``status ==
"complete"`` means every file it names is complete and from this config. A rerun of the same
config (same ``config_hash``) skips a complete job; anything else is redone. ``config_hash``
covers every key that changes the results (not ``out``, threads, logging or figures).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping, Optional

from eval.common.atomic import write_json_atomic
from eval.records.run_record import RECORD_NAME, RecordError, build_record, invalidate_record, read_record_json

RESULT_FILE = RECORD_NAME
# Keys that do not change any number a run produces.
VOLATILE_KEYS = ("out", "threads", "scene_workers", "logger", "hydra", "figures", "progress", "cache_dir")


def config_hash(cfg: Mapping[str, Any], *, volatile: tuple[str, ...] = VOLATILE_KEYS) -> str:
    """sha256 (16 hex digits) of the resolved config without the volatile keys."""
    plain = {k: v for k, v in cfg.items() if k not in volatile}
    blob = json.dumps(plain, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def read_result(run_dir: Path) -> Optional[dict]:
    """The run's result.json, or None if absent or not a valid record (a killed or foreign folder)."""
    try:
        return read_record_json(run_dir)
    except RecordError:
        return None


def is_complete(run_dir: Path, cfg_hash: str) -> bool:
    """True when ``run_dir`` holds a complete result of the same config."""
    rec = read_result(run_dir)
    return bool(rec and rec.get("status") == "complete" and rec.get("config_hash") == cfg_hash)


def invalidate_result(run_dir: Path) -> Optional[dict]:
    """Removes the folder's result.json before the job writes anything; returns the old record."""
    return invalidate_record(run_dir)


def write_result(run_dir: Path, **fields) -> Path:
    """Writes ``<run_dir>/result.json`` atomically (fields: eval.records.run_record.build_record); returns its path."""
    path = Path(run_dir) / RESULT_FILE
    write_json_atomic(path, build_record(**fields))
    return path
