"""What each step of a reproduction costs, in CPU-seconds: the constants behind the dry run's estimate.

``gspi-reproduce ... dry_run=true`` prints every step left with its estimate and their sum
(``gspi.reproduce.plan.cost_line``). Each estimate is a rate below times the step's count (its
scenes, or one call), except where a committed record says more: a Stage II training's rate is
its variant's CPU-seconds per step in the run log (``gspi.reproduce.table2.cpu_seconds_per_step``)
and a Table 1 or 3 sweep's is the ``seconds`` of its committed job records (the table config's
``timings``). Every rate names the machine and the record it came from; a step on another
machine or under other load takes what it takes (docs/REPRODUCE.md "Costs" for the spread).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Optional


@dataclass(frozen=True)
class Rate:
    """CPU-seconds per ``unit`` of a step, and where the figure came from."""

    cpu_s: float  # CPU-seconds per unit
    unit: str  # scene | call | training
    source: str  # the machine and the record


SMOKE_RUN = ("issue 68, the 2-core VM (1 core visible, load 8-11 from other jobs): the CPU-seconds "
             "each step logged (`done in N s (M CPU-s)`) in one gspi-reproduce call at scale=smoke")
SMALL_STEP = "not measured: a file copy or rewrite, about a second"

# scale -> step kind -> rate. A kind is what a step does; table2.py and sweep_tables.py name it.
RATES: dict[str, dict[str, Rate]] = {
    "cpu": {
        "data: pool": Rate(5.4, "scene", "session 31, 2-core AMD EPYC VM: gspi-data of Table 2's two pools, "
                                         "11 + 3.5 min on 2 workers for 224 + 96 scenes (docs/REPRODUCE.md)"),
        "data: view": Rate(2.0, "call", f"{SMOKE_RUN} (a view is symlinks: the same at any scale)"),
        "data: benchmark": Rate(15.0, "scene", "gspi-data preset=small, 22 scenes in 5.5 min on one worker "
                                               "(docs/REPRODUCE.md 'CPU scale')"),
        "stage 0": Rate(25.0, "scene", "session 31, 2-core AMD EPYC VM: recon=fast of the 224 + 32 pool "
                                       "scenes, 49 + 4.4 min on 2 workers (docs/REPRODUCE.md)"),
        "stage 1": Rate(3.0, "scene", "issue 66, 2-core VM beside 3 jobs: gspi.stage1.pool_clouds of the 32 "
                                      "held-out recon=fast assets, 1-4 s each"),
        "measure": Rate(9.4, "scene", "session 24, 2-core VM: Table 2's measure ~5 min for 32 held-out "
                                      "scenes (docs/REPRODUCE.md)"),
        "restore": Rate(1.0, "call", SMALL_STEP),
        "adopt": Rate(1.0, "call", SMALL_STEP),
        "commit": Rate(1.0, "call", SMALL_STEP),
        "table": Rate(1.0, "call", "issue 68, the 2-core VM: gspi-table over the committed Table 2 scores "
                                   "(17 runs, 10 000 bootstrap resamples), 0.86 s user + 0.14 s system"),
    },
    "smoke": {
        "data: pool": Rate(2.5, "scene", SMOKE_RUN),
        "data: view": Rate(2.0, "call", SMOKE_RUN),
        "data: benchmark": Rate(3.0, "scene", SMOKE_RUN),
        "stage 0": Rate(3.5, "scene", SMOKE_RUN),
        "stage 1": Rate(1.0, "scene", "not measured at this scale: Stage I of a 32-px asset, about a second"),
        "training": Rate(7.0, "training", SMOKE_RUN),
        "measure": Rate(4.0, "scene", SMOKE_RUN),
        "sweep: table1": Rate(115.0, "call", SMOKE_RUN),
        "sweep: table3": Rate(72.0, "call", SMOKE_RUN),
        "restore": Rate(1.0, "call", SMALL_STEP),
        "adopt": Rate(1.0, "call", SMALL_STEP),
        "commit": Rate(1.0, "call", SMALL_STEP),
        "table": Rate(1.0, "call", SMOKE_RUN),
    },
}


def rate(scale: str, kind: str) -> Optional[Rate]:
    """The rate of a step ``kind`` at ``scale`` (None: no figure for it)."""
    return RATES.get(scale, {}).get(kind)


def cost(scale: str, kind: str, count: int = 1) -> Optional[float]:
    """CPU-seconds of a step of ``kind`` over ``count`` units (None: no rate for it)."""
    r = rate(scale, kind)
    return None if r is None else r.cpu_s * count


def scene_count(ranges: Iterable[Iterable[int]]) -> int:
    """Scenes in pool index ranges ``[[a, b], ...]`` (b exclusive)."""
    return sum(b - a for a, b in ranges)


def preset_scene_count(conf_dir: Path, preset: str, overrides: Iterable[str]) -> Optional[int]:
    """Scenes ``gspi-data preset=<preset>`` writes: its train, val and test counts, only the
    ``data.only_splits=[...]`` of ``overrides`` when set (None: no such preset)."""
    import yaml

    path = conf_dir / "data" / f"{preset}.yaml"
    if not path.is_file():
        return None
    cfg = yaml.safe_load(path.read_text()) or {}
    splits = cfg.get("only_splits") or ["train", "val", "test"]
    for override in overrides:
        key, _, value = override.partition("=")
        if key == "data.only_splits":
            splits = yaml.safe_load(value) or splits
    return sum(int(cfg.get(f"num_{split}_scenes", 0)) for split in splits)


def recorded_job_seconds(records: Path) -> dict[int, float]:
    """{seed: the summed ``seconds`` of its jobs} over the committed job records under ``records``
    (each job's ``result.json``, as ``gspi.reproduce.sweep_tables.commit_sweep_records`` writes them)."""
    per_seed: dict[int, float] = {}
    for path in sorted(records.glob("*/result.json")):
        record = json.loads(path.read_text())
        if record.get("seconds") is not None:
            seed = int(record.get("seed", 0))
            per_seed[seed] = per_seed.get(seed, 0.0) + float(record["seconds"])
    return per_seed
