"""A Hydra job's own config (``<job>/.hydra/config.yaml``, written by Hydra) and how two differ.

``gspi-table`` refuses two configurations of one row (eval/sweep.py: check_one_config); the
message names the keys that differ, read from the jobs' saved configs, so a user sees *why*
(``table: table2 vs null``, ``stage2.checkpoint: ... vs null``) instead of two hashes.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

CONFIG_FILE = Path(".hydra") / "config.yaml"
IGNORED = ("out", "hydra", "threads", "scene_workers", "progress", "figures", "logger", "cache_dir")
SHOWN = 6  # keys named in a message


def read_job_config(job_dir: Path) -> dict[str, Any] | None:
    """The job's saved config as a flat ``{dotted key: value}``; None when absent or unreadable."""
    import yaml

    path = Path(job_dir) / CONFIG_FILE
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return None
    return flatten(data) if isinstance(data, dict) else None


def flatten(node: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(node, dict):
        return {prefix: node}
    out: dict[str, Any] = {}
    for key, value in node.items():
        out.update(flatten(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def config_differences(job_a: Path, job_b: Path) -> str:
    """``"differing keys: table: table2 vs None, stage2.checkpoint: x vs None"`` (at most SHOWN),
    or a sentence saying the saved configs could not be compared."""
    a, b = read_job_config(job_a), read_job_config(job_b)
    if a is None or b is None:
        missing = job_a if a is None else job_b
        return f"no readable {CONFIG_FILE} in {missing} to name the keys that differ"
    keys = sorted(k for k in set(a) | set(b)
                  if a.get(k) != b.get(k) and k.split(".")[0] not in IGNORED)
    if not keys:
        return "their saved configs differ only in keys that do not change a number"
    shown = ", ".join(f"{k}: {a.get(k)!r} vs {b.get(k)!r}" for k in keys[:SHOWN])
    more = f" and {len(keys) - SHOWN} more" if len(keys) > SHOWN else ""
    return f"differing keys: {shown}{more}"
