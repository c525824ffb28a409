"""An external system's runtime split into geometry and material (docs/BASELINES.md, "Runtimes").

A system whose recipe runs geometry and materials as separate commands names each command's
stage in its method config, `command_stages: [geometry, material, ...]` (one per command);
`Adapter.run` times every command and `gspi_runtime.json` keeps the per-stage sums. A system
trained in one joint command has no `command_stages`: only its total is known ("total only").

The result is always {"geometry", "material", "end_to_end"} in seconds (None = unknown):
* split:      geometry = sum of its geometry commands, material = the rest, end-to-end = all
              (None when no command is geometry: the geometry was made elsewhere, e.g. the
              user's mesh of MaterialAnything, and was not timed);
* total only: end-to-end = the total, geometry and material None.
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

STAGES = ("geometry", "material")


def command_stages(cfg: Mapping, num_commands: int) -> list[str] | None:
    """The validated `command_stages` of a method config (None when the system has none)."""
    stages = cfg.get("command_stages")
    if stages is None:
        return None
    if not isinstance(stages, (list, tuple)) or len(stages) != num_commands:
        raise ValueError(f"method {cfg.get('name')}: command_stages={stages!r} must list one stage per "
                         f"command ({num_commands} commands)")
    bad = [s for s in stages if s not in STAGES]
    if bad:
        raise ValueError(f"method {cfg.get('name')}: command_stages has {bad}; allowed: {', '.join(STAGES)}")
    return list(stages)


def split_seconds(seconds: list[float], stages: list[str] | None) -> dict:
    """{"geometry", "material", "end_to_end"} of timed commands (module docstring)."""
    total = float(sum(seconds))
    if stages is None:
        return {"geometry": None, "material": None, "end_to_end": total}
    geometry = sum(s for s, st in zip(seconds, stages) if st == "geometry")
    material = sum(s for s, st in zip(seconds, stages) if st == "material")
    has_geometry = "geometry" in stages
    return {"geometry": float(geometry) if has_geometry else None, "material": float(material),
            "end_to_end": total if has_geometry else None}


def given_runtime(value) -> dict:
    """A user's `runtime_s`: a number (the total: total only) or {geometry, material}."""
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(STAGES))
        if unknown or not set(value):
            raise ValueError(f"runtime_s={dict(value)!r}: a number (total seconds) or "
                             f"{{geometry: s, material: s}}")
        geometry, material = (None if value.get(k) is None else float(value[k]) for k in STAGES)
        end = None if geometry is None or material is None else geometry + material
        return {"geometry": geometry, "material": material, "end_to_end": end}
    return {"geometry": None, "material": None, "end_to_end": float(value)}


def read_runtime(src: Path, runtime_file: str) -> dict | None:
    """The runtime a timed `run` left in `<src>/<runtime_file>`, or None. Files written before
    the split held only "seconds": total only."""
    path = Path(src) / runtime_file
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    if "end_to_end" in data or "material" in data:
        return {k: data.get(k) for k in ("geometry", "material", "end_to_end")}
    return {"geometry": None, "material": None, "end_to_end": float(data["seconds"])}
