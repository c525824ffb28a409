"""Run records of a sweep (`result.json`, docs/TABLES.md) -> a tidy frame of per-scene values.

`gspi-run` writes `<run>/result.json` last and atomically; it names the evaluation folders of
the run (`material_eval`: a gspi-eval folder, `points_eval`: Stage II on the point cloud).
`load_sweep(paths)` finds every record below the given folders, validates it (errors name the
file and the problem), drops failed runs and duplicates (reported, never tabulated), counts
job folders without a record (killed mid-way), and returns one row per

    (method, ablation, table, seed, scene, measure, channel, metric) -> value

with measure "material" (eval_meta.json per_scene), "points" (points_eval/points_summary.json
per_scene), "runtime" (minutes) or "memory" (the run's peak RSS, MB). Values are in file units: PSNR dB, SSIM and LPIPS as
fractions. Nothing here knows how the runs were made.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from eval.common.errors import MissingInputError, StatedError
from eval.common.layout import read_json_object
from eval.protocol_id import protocol_hash, recorded_protocol
from eval.records.eval_folder import META_NAME, SUMMARY_NAME
from eval.records.run_points import run_points_path
from eval.records.run_record import RECORD_NAME, TABLES, RecordError, check_record, load_record_json
from eval.tables.labels import REFERENCE_ABLATION

CHANNELS = ("albedo", "roughness", "metallic", "relight")
METRICS = ("psnr", "ssim", "lpips")
COLUMNS = ["method", "ablation", "table", "seed", "scene", "measure", "channel", "metric",
           "value", "config_hash", "protocol", "data", "run"]
PREDICTION_DIRS = ("predictions", "pred")  # gspi-run writes predictions/; STYLE.md says pred/


class SweepError(StatedError, ValueError):
    """A run record or one of its evaluation files is malformed; the message names the file."""


@dataclass(frozen=True)
class RunRecord:
    """One parsed `result.json` (one Hydra job)."""

    path: Path                     # the result.json
    status: str                    # complete | failed
    error: str | None
    method: str
    ablation: str                  # "full" when the record has null
    table: str | None              # table1 | table2 | table3 (inferred when null, see infer_table)
    seed: int
    config_hash: str
    data: str | None
    scenes: tuple[str, ...]
    material_eval: Path | None     # absolute folder, None if the run has none
    points_eval: Path | None
    mtime: float                   # of result.json; the newest of duplicates is kept
    untabled: bool = False         # `table` null in the record (a run of no experiment)

    @property
    def run_dir(self) -> Path:
        return self.path.parent

    @property
    def identity(self) -> tuple:
        """Two complete records with the same identity are one run. The table is part of it:
        the full model run for Table 2 and for Table 3 are two rows even if configured alike."""
        return (self.table, self.method, self.ablation, self.seed, self.config_hash)


@dataclass
class Sweep:
    """Everything `gspi-table` reports about a set of sweep folders."""

    values: pd.DataFrame                               # COLUMNS, one row per value
    records: list[RunRecord]                           # complete, de-duplicated
    failed: list[RunRecord] = field(default_factory=list)
    superseded: list[RunRecord] = field(default_factory=list)  # failed, later completed
    unfinished: list[Path] = field(default_factory=list)       # job folders without a record
    notes: list[str] = field(default_factory=list)              # duplicates, missing scenes
    protocols: dict = field(default_factory=dict)  # run folder -> resolved material protocol
    counts: dict = field(default_factory=dict)     # run folder -> eval_meta.json image counts
    specs: dict = field(default_factory=dict)      # table name -> TableSpec, where a source measures differently


def infer_table(method: str, ablation: str) -> str:
    """Table of a record whose `table` is null: a1-a5 -> table2, a6-a9 -> table3, else table1."""
    match = re.match(r"a(\d)(?:_|$)", ablation)
    if match and 1 <= int(match.group(1)) <= 5:
        return "table2"
    if match and 6 <= int(match.group(1)) <= 9:
        return "table3"
    return "table1"


def _read_json(path: Path, what: str) -> dict:
    return read_json_object(path, error=SweepError, what=what)


def _subfolder(path: Path, data: dict, key: str) -> Path | None:
    name = data.get(key)
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise SweepError(f"{path}: {key} must be a folder name or null, got {name!r}")
    folder = path.parent / name
    if not folder.is_dir():
        raise SweepError(f"{path}: {key} names {name!r} but {folder} is not a folder")
    return folder


def read_record(path: str | Path) -> RunRecord:
    """Parse and validate one `result.json` (docs/TABLES.md, "Run record")."""
    path = Path(path)
    try:  # the one schema (eval/records/run_record.py), shared with the writer
        data = load_record_json(path)
        check_record(data, path)
    except RecordError as exc:
        raise SweepError(str(exc)) from exc
    method, ablation = str(data["method"]), str(data["ablation"] or "full")
    complete = data["status"] == "complete"
    material = _subfolder(path, data, "material_eval") if complete else None
    points = _subfolder(path, data, "points_eval") if complete else None
    if complete and material is None and points is None:
        raise SweepError(f"{path}: a complete record must name material_eval or points_eval")
    return RunRecord(path=path, status=data["status"], error=data.get("error"), method=method,
                     ablation=ablation, table=data.get("table") or infer_table(method, ablation),
                     seed=data["seed"], config_hash=str(data["config_hash"]),
                     data=data.get("data"), scenes=tuple(data.get("scenes") or ()),
                     material_eval=material, points_eval=points, mtime=path.stat().st_mtime,
                     untabled=data.get("table") is None)


def find_records(paths: list[str | Path]) -> tuple[list[Path], list[Path]]:
    """(result.json files, unfinished job folders) below the given folders, recursively.

    An unfinished job folder is an outermost Hydra output folder (it has `.hydra/`, no folder
    above it does, and none above it holds a result.json) with no result.json and no
    summary.json: the job was killed before it wrote its record, so nothing in it is
    tabulated. A finished gspi-eval folder (.hydra/ + summary.json) is not a job folder.
    """
    records, hydra_dirs = set(), set()
    for p in map(Path, paths):
        if not p.exists():
            raise MissingInputError(f"{p}: run folder not found")
        records |= {r for r in p.rglob(RECORD_NAME) if r.is_file()}
        hydra_dirs |= {h.parent for h in p.rglob(".hydra") if h.is_dir()}
    owners = hydra_dirs | {r.parent for r in records}
    unfinished = {d for d in hydra_dirs
                  if not (d / RECORD_NAME).is_file() and not (d / SUMMARY_NAME).is_file()
                  and not any(a in owners for a in d.parents)}
    return sorted(records), sorted(unfinished)


def _finite_or_inf(value, where: str) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or math.isnan(value):
        raise SweepError(f"{where}: expected a number, got {value!r}")
    return float(value)


def per_scene_rows(per_scene: dict, where: Path, measure: str) -> list[dict]:
    """{scene: {channel: {metric: value}}} -> rows; unknown channels (e.g. "avg") are skipped:
    channel averages are recomputed by the tables, one definition for every measure."""
    if not isinstance(per_scene, dict) or not per_scene:
        raise SweepError(f"{where}: 'per_scene' must be a non-empty {{scene: {{channel: "
                         f"{{psnr, ssim, lpips}}}}}} object")
    rows = []
    for scene, channels in per_scene.items():
        if not isinstance(channels, dict):
            raise SweepError(f"{where}: per_scene.{scene} must be a {{channel: ...}} object")
        for channel, metrics in channels.items():
            if channel not in CHANNELS:
                continue
            if not isinstance(metrics, dict):
                raise SweepError(f"{where}: per_scene.{scene}.{channel} must be a "
                                 "{psnr, ssim, lpips} object")
            for metric in METRICS:
                if metric not in metrics:
                    raise SweepError(f"{where}: per_scene.{scene}.{channel} lacks {metric!r}")
                value = _finite_or_inf(metrics[metric],
                                       f"{where}: per_scene.{scene}.{channel}.{metric}")
                rows.append({"scene": str(scene), "measure": measure, "channel": channel,
                             "metric": metric, "value": value})
    return rows


def _runtime_rows(record: RunRecord, eval_meta: dict, scenes: list[str]) -> list[dict]:
    """Per-scene minutes from `<run>/{predictions,pred}/<scene>/meta.json` (runtime_s) when
    every scene has one, else the run's mean from eval_meta.json (runtime_min) as one unit,
    scene "*"."""
    metas = []
    for folder in PREDICTION_DIRS:
        metas = [record.run_dir / folder / s / "meta.json" for s in scenes]
        if scenes and all(m.is_file() for m in metas):
            break
    rows = []
    if scenes and all(m.is_file() for m in metas):
        for scene, meta_path in zip(scenes, metas):
            runtime = _read_json(meta_path, "prediction meta.json").get("runtime_s") or {}
            for key in ("material", "end_to_end"):
                if runtime.get(key) is not None:
                    rows.append({"scene": scene, "channel": key, "value": runtime[key] / 60.0})
    else:
        return runtime_min_rows(eval_meta)
    return [dict(r, measure="runtime", metric="minutes") for r in rows]


def runtime_min_rows(eval_meta: dict) -> list[dict]:
    """The run's mean minutes from eval_meta.json (runtime_min) as one unit, scene "*"."""
    runtime = eval_meta.get("runtime_min") or {}
    return [{"scene": "*", "measure": "runtime", "channel": key, "metric": "minutes",
             "value": float(runtime[key])}
            for key in ("material", "end_to_end") if runtime.get(key) is not None]


def peak_memory_rows(eval_meta: dict) -> list[dict]:
    """The run's peak resident memory (eval_meta.json peak_memory_mb.rss: the largest of any
    stage of any scene) as one unit, scene "*"; none when the predictions did not record it."""
    rss = (eval_meta.get("peak_memory_mb") or {}).get("rss")
    return [] if rss is None else [{"scene": "*", "measure": "memory", "channel": "peak_rss",
                                    "metric": "mb", "value": float(rss)}]


def material_protocol_label(eval_meta: dict) -> str:
    """"name vN #hash" of the protocol an eval_meta.json records."""
    return (protocol_name(eval_meta.get("protocol"), "unnamed protocol")
            + f" #{protocol_hash(recorded_protocol(eval_meta))}")


def protocol_name(protocol, default: str) -> str:
    """"name vN" of a {"name", "version"} object, a string as given, else `default`."""
    if isinstance(protocol, dict):
        return f"{protocol.get('name')} v{protocol.get('version')}"
    return str(protocol) if protocol else default


def record_values(record: RunRecord) -> tuple[list[dict], list[str]]:
    """Rows (without the record's own columns) and notes (scenes the record lists but lacks)."""
    rows, notes, protocol = [], [], {}
    if record.material_eval is not None:
        meta_path = record.material_eval / META_NAME
        meta = _read_json(meta_path, f"{META_NAME} of material_eval")
        _read_json(record.material_eval / SUMMARY_NAME, f"{SUMMARY_NAME} of material_eval")
        material = per_scene_rows(meta.get("per_scene"), meta_path, "material")
        protocol["material"] = material_protocol_label(meta)
        rows += (material + _runtime_rows(record, meta, sorted({r["scene"] for r in material}))
                 + peak_memory_rows(meta))
    if record.points_eval is not None:
        summary_path = run_points_path(record.points_eval)
        summary = _read_json(summary_path, f"{summary_path.name} of points_eval")
        rows += per_scene_rows(summary.get("per_scene"), summary_path, "points")
        protocol["points"] = protocol_name(summary.get("protocol"), "points-eval")
    present = {r["scene"] for r in rows}
    lacking = [s for s in record.scenes if s not in present]
    if lacking:
        notes.append(f"{record.path}: no scores for listed scene(s) {lacking}")
    for r in rows:
        r["protocol"] = protocol.get(r["measure"], protocol.get("material", ""))
    return rows, notes


def deduplicate(records: list[RunRecord]) -> tuple[list[RunRecord], list[str]]:
    """Keep the newest (result.json mtime) of complete records with one identity; say so."""
    groups: dict[tuple, list[RunRecord]] = {}
    for rec in records:
        groups.setdefault(rec.identity, []).append(rec)
    kept, notes = [], []
    for identity, group in groups.items():
        group.sort(key=lambda r: (r.mtime, str(r.path)))
        kept.append(group[-1])
        if len(group) > 1:
            notes.append(f"{len(group)} records of {identity[0]} method={identity[1]} "
                         f"ablation={identity[2]} seed={identity[3]} config={identity[4]}: "
                         "kept the newest "
                         f"{group[-1].path}, ignored {', '.join(str(r.path) for r in group[:-1])}")
    return kept, notes


def check_one_config(records: list[RunRecord]) -> None:
    """Refuse two configurations of one (table, method, ablation, seed): a row would mix them.
    The error names the config keys that differ (from each job's ``.hydra/config.yaml``)."""
    from eval.records.job_config import config_differences

    seen: dict[tuple, RunRecord] = {}
    for rec in records:
        other = seen.setdefault((rec.table, rec.method, rec.ablation, rec.seed), rec)
        if other.config_hash != rec.config_hash:
            raise SweepError(f"{rec.path} and {other.path}: {rec.table} method={rec.method} "
                             f"ablation={rec.ablation} seed={rec.seed} was run with two "
                             f"configurations ({other.config_hash} vs {rec.config_hash}; "
                             f"{config_differences(other.run_dir, rec.run_dir)}); "
                             "tabulate one sweep at a time")


REFERENCE_ROW = ("gspi", REFERENCE_ABLATION)  # the row every table's Δ compares with (eval.tables.build)


def with_reference_rows(records: list[RunRecord]) -> list[RunRecord]:
    """``records`` plus, for each ablation table (2, 3) the sweep has rows of, the Full run of no
    experiment (``table`` null, so filed under Table 1) as that table's reference row, unless the
    table has its own Full of that seed: ``gspi-run -m ablation=full,a1_...,a6_...`` gives Tables
    2 and 3 their Δ column as the per-table sweeps do (issue 54)."""
    from dataclasses import replace

    present = {(r.table, r.method, r.ablation, r.seed) for r in records}
    ablation_tables = {r.table for r in records if r.table in ("table2", "table3")}
    extra = [replace(r, table=table) for r in records
             if r.untabled and (r.method, r.ablation) == REFERENCE_ROW
             for table in sorted(ablation_tables)
             if (table, *REFERENCE_ROW, r.seed) not in present]
    return records + extra


@dataclass(frozen=True)
class JobRow:
    """The row a job without a complete record was meant for: a failed record's, or an unfinished
    job folder's (read from its saved ``.hydra/config.yaml``)."""

    table: str
    method: str
    ablation: str
    seed: int | None
    run_dir: Path
    why: str            # "failed" | "no result.json"


def unfinished_job_row(job_dir: Path) -> JobRow | None:
    """The row of a job folder killed before its record, from its saved config; None if unreadable."""
    from eval.records.job_config import read_job_config

    cfg = read_job_config(job_dir)
    if not cfg or "method.name" not in cfg:
        return None
    method, ablation = str(cfg["method.name"]), str(cfg.get("ablation_name") or "full")
    seed = cfg.get("seed")
    return JobRow(table=str(cfg.get("table") or infer_table(method, ablation)), method=method,
                  ablation=ablation, seed=seed if isinstance(seed, int) else None, run_dir=job_dir,
                  why="no result.json")


def jobs_without_rows(sweep: "Sweep", table: str) -> list[JobRow]:
    """The failed and unfinished jobs of ``table`` (their rows are missing or have fewer runs)."""
    rows = [JobRow(r.table, r.method, r.ablation, r.seed, r.run_dir, "failed")
            for r in sweep.failed if r.table == table]
    rows += [j for j in map(unfinished_job_row, sweep.unfinished) if j is not None and j.table == table]
    return rows


def load_sweep(paths: list[str | Path], *, tables: tuple[str, ...] = TABLES) -> Sweep:
    """Find, validate and flatten every run record below `paths` (only those of `tables`)."""
    files, unfinished = find_records(paths)
    parsed = list(map(read_record, files))
    complete, notes = deduplicate([r for r in parsed if r.status == "complete"])
    complete = [r for r in with_reference_rows(complete) if r.table in tables]
    parsed = [r for r in parsed if r.table in tables]
    check_one_config(complete)
    done = {r.identity for r in complete}
    failed = [r for r in parsed if r.status == "failed" and r.identity not in done]
    superseded = [r for r in parsed if r.status == "failed" and r.identity in done]
    rows, protocols, counts = [], {}, {}
    for rec in sorted(complete, key=lambda r: (r.table, r.method, r.ablation, r.seed)):
        if rec.material_eval is not None:
            meta = _read_json(rec.material_eval / META_NAME, f"{META_NAME} of material_eval")
            protocols[str(rec.run_dir)] = recorded_protocol(meta)
            counts[str(rec.run_dir)] = meta.get("counts") or {}
        values, lacking = record_values(rec)
        notes += lacking
        own = {"method": rec.method, "ablation": rec.ablation, "table": rec.table,
               "seed": rec.seed, "config_hash": rec.config_hash, "data": rec.data or "",
               "run": str(rec.run_dir)}
        rows += [dict(own, **v) for v in values]
    frame = pd.DataFrame(rows, columns=COLUMNS)
    return Sweep(values=frame, records=complete, failed=failed, superseded=superseded,
                 unfinished=unfinished, notes=notes, protocols=protocols, counts=counts)
