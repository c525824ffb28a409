"""The run record `result.json` (docs/TABLES.md): what a finished or failed job leaves behind.

It is written LAST and atomically, so its presence with ``status == "complete"`` means every
file it names is complete. A rerun of the same config (same ``config_hash``) skips a
complete job; anything else is redone. ``config_hash`` covers every key that changes the
results (not ``out``, threads, logging or figures).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping, Optional

from eval.layout import write_json_atomic

RESULT_FILE = "result.json"
FORMAT = "gspi-run"
FORMAT_VERSION = 1
# Keys that do not change any number a run produces.
VOLATILE_KEYS = ("out", "threads", "scene_workers", "logger", "hydra", "figures", "progress", "cache_dir")


def config_hash(cfg: Mapping[str, Any], *, volatile: tuple[str, ...] = VOLATILE_KEYS) -> str:
    """sha256 (16 hex digits) of the resolved config without the volatile keys."""
    plain = {k: v for k, v in cfg.items() if k not in volatile}
    blob = json.dumps(plain, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def read_result(run_dir: Path) -> Optional[dict]:
    """The run's result.json, or None if absent or unreadable (a killed or foreign folder)."""
    path = Path(run_dir) / RESULT_FILE
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("format") == FORMAT else None


def is_complete(run_dir: Path, cfg_hash: str) -> bool:
    """True when ``run_dir`` holds a complete result of the same config."""
    rec = read_result(run_dir)
    return bool(rec and rec.get("status") == "complete" and rec.get("config_hash") == cfg_hash)


def write_result(run_dir: Path, *, status: str, cfg_hash: str, method: str, ablation: str,
                 table: Optional[str], seed: int, data: str, scenes: list[str], error: Optional[str] = None,
                 material_eval: Optional[str] = None, points_eval: Optional[str] = None,
                 extra: Optional[dict] = None) -> Path:
    """Writes ``<run_dir>/result.json`` atomically; returns its path."""
    if status not in ("complete", "failed"):
        raise ValueError(f"status must be 'complete' or 'failed', got {status!r}")
    record = {"format": FORMAT, "format_version": FORMAT_VERSION, "status": status, "error": error,
              "method": method, "ablation": ablation, "table": table, "seed": int(seed),
              "config_hash": cfg_hash, "data": data, "scenes": list(scenes),
              "material_eval": material_eval, "points_eval": points_eval, **(extra or {})}
    path = Path(run_dir) / RESULT_FILE
    write_json_atomic(path, record)
    return path
