"""Tables 1-3 from a sweep: cells mean ± SE over (scene, seed) units, Δ vs the full model.

Averaging order (docs/TABLES.md): per view -> per scene (the evaluation files' `per_scene`)
-> for "avg" columns the mean of albedo, roughness and metallic within each (scene, seed)
unit -> mean ± standard error over the units of a row (every scene x every seed). The Δ
column is the paired bootstrap of the main metric (PSNR) against the reference row (GS-PI,
ablation "full"), paired on (scene, seed). Rendering is in `eval.tables.render`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import pandas as pd

from eval.protocol_id import ProtocolMixError, check_one_protocol, describe_counts, describe_protocol, sum_counts
from eval.stats import mean_and_sem, paired_bootstrap_ci, paired_differences
from eval.sweep import REFERENCE_ROW, Sweep, SweepError, jobs_without_rows
from eval.tables.labels import row_label, row_order

AVG_CHANNELS = ("albedo", "roughness", "metallic")
UNIT = ["method", "ablation", "scene", "seed"]


@dataclass(frozen=True)
class Column:
    """One numeric column: a metric of a channel ("avg" = mean of AVG_CHANNELS) of a measure."""

    measure: str      # material | points | runtime | memory
    channel: str      # albedo | roughness | metallic | relight | avg | material | end_to_end | peak_rss
    metric: str       # psnr | ssim | lpips | minutes | mb
    ranked: bool = True

    @property
    def key(self) -> str:
        return f"{self.metric}/{self.channel}"

    @property
    def scale(self) -> float:
        """File units -> display units: SSIM and LPIPS fractions are shown in %."""
        return 100.0 if self.metric in ("ssim", "lpips") else 1.0

    @property
    def higher_is_better(self) -> bool:
        return self.metric in ("psnr", "ssim")


@dataclass(frozen=True)
class TableSpec:
    """What one paper table shows: its columns, the measure and the Δ column's metric."""

    name: str
    title: str
    row_header: str
    columns: tuple[Column, ...]
    delta: Column
    averaging: str    # one sentence for the footer: what a cell averages


RUNTIME_COLUMNS = (Column("runtime", "material", "minutes"),
                   Column("runtime", "end_to_end", "minutes", ranked=False))
MEMORY_COLUMN = Column("memory", "peak_rss", "mb", ranked=False)


def _metric_columns(measure: str, channels: tuple[str, ...]) -> tuple[Column, ...]:
    return tuple(Column(measure, c, m) for m in ("psnr", "ssim", "lpips") for c in channels)


TABLE_SPECS = {
    "table1": TableSpec(
        "table1", "Table 1: comparison with methods (material maps and relighting, test views)",
        "Method", _metric_columns("material", ("albedo", "roughness", "metallic", "relight"))
        + RUNTIME_COLUMNS,
        Column("material", "relight", "psnr"),
        "per scene: mean over its test views (relight: views x held-out environments)"),
    "table2": TableSpec(
        "table2", "Table 2: Stage II ablations (generated point cloud)", "Stage 2 Variant",
        _metric_columns("points", ("avg",)), Column("points", "avg", "psnr"),
        "per scene: mean over the lattice views of the generated point cloud (points_eval), "
        "then over albedo, roughness, metallic"),
    "table3": TableSpec(
        "table3", "Table 3: Stage III ablations (distilled Gaussians, test views)",
        "Stage 3 Variant", _metric_columns("material", ("avg",)),
        Column("material", "avg", "psnr"),
        "per scene: mean over its test views (material_eval), then over albedo, roughness, "
        "metallic"),
}


def with_resources(spec: TableSpec) -> TableSpec:
    """``spec`` plus the time column (if it lacks one) and the peak-memory column
    (gspi-table resources=true); "--" where a run did not record them."""
    extra = () if any(c.measure == "runtime" for c in spec.columns) else RUNTIME_COLUMNS
    return replace(spec, columns=spec.columns + extra + (MEMORY_COLUMN,))


@dataclass
class SweepTable:
    """A built table: per row and column mean/sem/n, marks, Δ and the per-scene breakdown."""

    spec: TableSpec
    rows: list[tuple[str, str]]          # (method, ablation) in the paper's order
    labels: list[str]
    mean: pd.DataFrame                   # label x column key, display units
    sem: pd.DataFrame
    count: pd.DataFrame                  # units per cell
    marks: pd.DataFrame                  # 1 best, 2 second, 0 otherwise
    delta: pd.DataFrame                  # label x (mean, lo, hi, n_pairs); NaN where undefined
    per_scene: pd.DataFrame              # scene x label: Δ metric, mean over seeds
    reference: str | None                # label of the reference row
    notes: list[str] = field(default_factory=list)
    protocol: str = ""
    counts: str = ""                     # images per channel (and at the PSNR floor), all runs
    data: str = ""
    bootstrap: dict = field(default_factory=dict)


def unit_values(values: pd.DataFrame, column: Column) -> pd.Series:
    """Per-unit values of a column in display units, indexed by (method, ablation, scene, seed).

    "avg" is the mean of the three material channels within a unit; a unit lacking one of
    them has no average (it is dropped, so n counts only units with all three).
    """
    sel = values[(values["measure"] == column.measure) & (values["metric"] == column.metric)]
    if column.channel == "avg":
        sel = sel[sel["channel"].isin(AVG_CHANNELS)]
        wide = sel.groupby(UNIT + ["channel"])["value"].mean().unstack("channel")
        series = wide.reindex(columns=list(AVG_CHANNELS)).mean(axis=1, skipna=False).dropna()
    else:
        series = sel[sel["channel"] == column.channel].groupby(UNIT)["value"].mean()
    return series * column.scale


def _row_units(units: pd.Series, row: tuple[str, str]) -> dict[tuple, float]:
    """{(scene, seed): value} of one row."""
    if units.empty:
        return {}
    mine = units[(units.index.get_level_values("method") == row[0])
                 & (units.index.get_level_values("ablation") == row[1])]
    return {(s, int(k)): float(v) for (_, _, s, k), v in mine.items()}


def rank_marks(mean: pd.DataFrame, columns: tuple[Column, ...]) -> pd.DataFrame:
    """1 = best, 2 = second best per ranked column (by mean); +inf PSNR counts as best."""
    marks = pd.DataFrame(0, index=mean.index, columns=mean.columns)
    for col in columns:
        if not col.ranked:
            continue
        values = mean[col.key].dropna()
        values = values[values.map(lambda v: math.isfinite(v) or col.higher_is_better)]
        order = values.sort_values(ascending=not col.higher_is_better, kind="stable").index
        for rank, label in enumerate(list(order)[:2], start=1):
            marks.loc[label, col.key] = rank
    return marks


def _single_value(values: pd.DataFrame, name: str, spec: TableSpec, what: str) -> str:
    found = sorted({v for v in values[name].unique() if v})
    if len(found) > 1 and name == "protocol":
        raise SweepError(f"{spec.name}: runs were evaluated under different {what} {found}: "
                         "tables never mix protocol versions")
    return ", ".join(found)


def _material_runs(values: pd.DataFrame) -> list[str]:
    return sorted(values.loc[values["measure"] == "material", "run"].unique())


def _table_protocol(sweep, values: pd.DataFrame, spec: TableSpec) -> str:
    """Every knob of the one protocol the table's material scores share; refuses two (the
    error names the runs and the keys that differ). Other measures: their names."""
    runs = {r: sweep.protocols[r] for r in _material_runs(values) if r in sweep.protocols}
    if runs:
        try:
            check_one_protocol(runs)
        except ProtocolMixError as exc:
            raise ProtocolMixError(f"{spec.name}: {exc}") from None
        others = values.loc[values["measure"] == "points", "protocol"]  # runtime rows: material's
        other = sorted({v for v in others.unique() if v})
        return "; ".join([describe_protocol(next(iter(runs.values())))] + other)
    return _single_value(values, "protocol", spec, "protocols")


def _table_data(values: pd.DataFrame, spec: TableSpec) -> str:
    """The datasets of the table; a row (method, ablation) whose runs were scored on different
    datasets is refused, naming the runs: its mean would mix them."""
    for (method, ablation), rows in values.groupby(["method", "ablation"]):
        found = sorted({d for d in rows["data"].unique() if d})
        if len(found) > 1:
            runs = [f"{run}: {data}" for run, data in
                    sorted(set(zip(rows["run"], rows["data"])))]
            raise SweepError(f"{spec.name}: method={method} ablation={ablation} was scored on "
                             f"different datasets {found}:\n  " + "\n  ".join(runs))
    return _single_value(values, "data", spec, "datasets")


def _delta_table(units: pd.Series, rows, labels, reference, bootstrap: dict, notes: list[str]
                 ) -> pd.DataFrame:
    delta = pd.DataFrame(math.nan, index=labels, columns=["mean", "lo", "hi", "n_pairs"])
    if reference is None:
        notes.append("no reference row (GS-PI, ablation full): no Δ column")
        return delta
    ref_units = _row_units(units, REFERENCE_ROW)
    for row, label in zip(rows, labels):
        if row == REFERENCE_ROW:
            continue
        mine = _row_units(units, row)
        pairs = len(paired_differences(mine, ref_units))
        try:
            delta.loc[label, ["mean", "lo", "hi"]] = paired_bootstrap_ci(
                mine, ref_units, n_resamples=bootstrap["n"], confidence=bootstrap["confidence"],
                seed=bootstrap["seed"])
        except ValueError as exc:
            notes.append(f"Δ of {label!r} not computed: {exc}")
        delta.loc[label, "n_pairs"] = pairs
    return delta


def per_scene_breakdown(units: pd.Series, rows, labels) -> pd.DataFrame:
    """scene x row label: the unit values averaged over seeds."""
    out = {}
    for row, label in zip(rows, labels):
        mine = _row_units(units, row)
        by_scene: dict[str, list[float]] = {}
        for (scene, _), value in mine.items():
            by_scene.setdefault(scene, []).append(value)
        out[label] = {s: mean_and_sem(v)[0] for s, v in by_scene.items()}
    frame = pd.DataFrame(out, columns=labels)
    frame.index.name = "scene"
    return frame.sort_index()


def build_sweep_table(sweep: Sweep, spec: TableSpec, *, bootstrap: dict | None = None
                      ) -> SweepTable | None:
    """The table `spec` from the sweep's complete records of that table; None if it has none.

    Args:
        bootstrap: {"n": resamples, "seed": int, "confidence": (0, 1)} for the Δ column.
    """
    bootstrap = {"n": 10000, "seed": 0, "confidence": 0.95, **(bootstrap or {})}
    measures = {c.measure for c in spec.columns}
    values = sweep.values[(sweep.values["table"] == spec.name)
                          & sweep.values["measure"].isin(measures)]
    if values.empty:
        return None
    rows = sorted(set(zip(values["method"], values["ablation"])), key=lambda r: row_order(*r))
    labels = [row_label(m, a, spec.name) for m, a in rows]
    if len(set(labels)) != len(labels):
        raise SweepError(f"{spec.name}: two rows share a label in {labels}")
    stats = {"mean": {}, "sem": {}, "count": {}}
    for col in spec.columns:
        units = unit_values(values, col)
        for row, label in zip(rows, labels):
            m, s, n = mean_and_sem(_row_units(units, row).values())
            for name, v in zip(stats, (m, s, n)):
                stats[name].setdefault(col.key, {})[label] = v
    frames = {k: pd.DataFrame(v, index=labels, columns=[c.key for c in spec.columns])
              for k, v in stats.items()}
    notes: list[str] = []
    reference = row_label(*REFERENCE_ROW, spec.name) if REFERENCE_ROW in rows else None
    delta_units = unit_values(values, spec.delta)
    return SweepTable(
        spec=spec, rows=rows, labels=labels, mean=frames["mean"], sem=frames["sem"],
        count=frames["count"], marks=rank_marks(frames["mean"], spec.columns),
        delta=_delta_table(delta_units, rows, labels, reference, bootstrap, notes),
        per_scene=per_scene_breakdown(delta_units, rows, labels), reference=reference,
        notes=notes, protocol=_table_protocol(sweep, values, spec),
        counts=describe_counts(sum_counts([sweep.counts.get(r) for r in _material_runs(values)])),
        data=_table_data(values, spec), bootstrap=bootstrap)


def rows_with_failed_jobs(sweep: Sweep, table: str, shown_rows=()) -> list[str]:
    """One phrase per row (method, ablation) of ``table`` that has failed or unfinished jobs:
    its paper label, the counts, and whether it is missing from the table or shown from its
    complete runs only (``shown_rows``: the table's rows), so no row disappears silently."""
    groups: dict[tuple, list] = {}
    for job in jobs_without_rows(sweep, table):
        groups.setdefault((job.method, job.ablation), []).append(job)
    out = []
    for (method, ablation), jobs in sorted(groups.items(), key=lambda kv: row_order(*kv[0])):
        failed = sum(j.why == "failed" for j in jobs)
        counts = ", ".join(c for c in (f"{failed} failed job(s)" if failed else "",
                                       f"{len(jobs) - failed} job(s) without result.json"
                                       if len(jobs) > failed else "") if c)
        where = "shown from its complete runs only" if (method, ablation) in shown_rows else "missing from the table"
        out.append(f"{row_label(method, ablation, table)} (method={method} ablation={ablation}: {counts}, "
                   f"{where}: {', '.join(str(j.run_dir) for j in jobs)})")
    return out
