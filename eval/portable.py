"""Scores as committed: no absolute path of the machine that measured them (issue 53).

A ``scores.json`` of ``gspi.stage2.evaluate_points`` names the dataset, the checkpoint and the
baseline's training data by absolute path. The committed copy names the measured data by a
label (``data``: what ``gspi-table`` checks every row shares, e.g. ``parts_pool[224:256]/recon=fast``)
and every other absolute path relative to a named root (``<work>/runs/full_s0/checkpoint.pt``),
or by its last two parts (never its top-level folder) when it lies under none.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping


def portable_path(text: str, roots: Mapping[str, Path]) -> str:
    """An absolute path as ``<root name>/relative`` (a root named "" gives the bare relative path);
    other strings unchanged."""
    if not text.startswith("/"):
        return text
    path = Path(text)
    for name, root in roots.items():
        try:
            rel = path.relative_to(Path(root).resolve())
        except ValueError:
            continue
        return f"{name}/{rel}" if name else str(rel)
    # its last two parts, never the top-level folder (a machine's mount: /work, /home, /Users)
    kept = path.parts[max(2, len(path.parts) - 2):] or path.parts[-1:]
    return "<elsewhere>/" + "/".join(kept)


def portable(value: Any, roots: Mapping[str, Path]) -> Any:
    """``value`` (JSON) with every absolute path string made portable."""
    if isinstance(value, dict):
        return {k: portable(v, roots) for k, v in value.items()}
    if isinstance(value, list):
        return [portable(v, roots) for v in value]
    return portable_path(value, roots) if isinstance(value, str) else value


def write_portable_scores(src: Path, dst: Path, *, data_label: str, roots: Mapping[str, Path]) -> Path:
    """``dst`` = ``src``'s scores with ``data`` = ``data_label`` and portable paths (atomically)."""
    from eval.common.atomic import write_json_atomic

    scores = json.loads(Path(src).read_text())
    scores = {**portable(scores, roots), "data": data_label}
    dst.parent.mkdir(parents=True, exist_ok=True)
    return write_json_atomic(dst, scores, allow_nan=True)
