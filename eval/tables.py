"""`gspi-table`: evaluated runs -> the paper's Table 1 layout (Markdown, LaTeX, CSV).

    gspi-table runs/gspi/eval runs/no_decomposition/eval out=tables
    gspi-table 'runs=[runs/a/eval,runs/b/eval]' out=tables
    gspi-table multirun/2025-01-01/12-00-00 out=tables             # a gspi-run sweep
    gspi-table multirun/... table=table2 bootstrap.n=20000 bootstrap.seed=1

Sweeps: when the folders hold gspi-run records (result.json, docs/TABLES.md), Tables 1-3 are
built from them with mean ± SE, Δ vs the full model and a per-scene breakdown
(`eval.sweep`, `eval.tables_sweep`, `eval.tables_render`). Otherwise, plain gspi-eval folders:
each run folder (searched recursively) holds a summary.json and eval_meta.json written by
gspi-eval. Rows are methods (runs of the same method are averaged); column groups are PSNR,
SSIM(%), LPIPS(%) over albedo, roughness, metallic, relight, then the runtime in minutes,
"material (end-to-end)". "--" marks a channel the method does not model; the best value of a
column is bold (LaTeX: red cell) and the second best underlined (LaTeX: yellow cell).
Numbers are never typed by hand: every cell comes from a summary.json.
"""
from __future__ import annotations

import logging
import math
import sys
from pathlib import Path

import pandas as pd

from eval.protocol_id import (check_one_protocol, describe_counts, describe_protocol,
                              recorded_protocol, sum_counts)
from eval.tables_render import write_text_atomic

log = logging.getLogger(__name__)

CHANNELS = ("albedo", "roughness", "metallic", "relight")
METRICS = (("psnr", "PSNR↑", 1.0, True), ("ssim", "SSIM(%)↑", 100.0, True),
           ("lpips", "LPIPS(%)↓", 100.0, False))
RUNTIME = "runtime"
LATEX_COLORS = (r"\definecolor{BaselineBestCell}{RGB}{255,235,238}" "\n"
                r"\definecolor{BaselineSecondCell}{RGB}{255,249,196}")


def find_runs(paths: list[str | Path]) -> list[Path]:
    """Complete gspi-eval folders (summary.json and eval_meta.json), searched recursively
    below each given path; incomplete ones are left out (see `find_incomplete`)."""
    found = []
    for p in map(Path, paths):
        if not p.exists():
            raise FileNotFoundError(f"{p}: run folder not found")
        found += sorted({s.parent for s in p.rglob("summary.json")} |
                        ({p} if (p / "summary.json").is_file() else set()))
    complete = sorted(d for d in set(found) if (d / "eval_meta.json").is_file())
    if not complete:
        bad = find_incomplete(paths)
        raise FileNotFoundError(f"no complete gspi-eval folder (summary.json + eval_meta.json) "
                                f"below {', '.join(map(str, paths))}"
                                + (f"; incomplete (killed?) folders: {', '.join(map(str, bad))}"
                                   if bad else ""))
    return complete


def find_incomplete(paths: list[str | Path]) -> list[Path]:
    """gspi-eval folders a killed run left: summary.json without eval_meta.json (the last file
    written), or a Hydra output folder (.hydra/) with neither summary.json nor result.json."""
    bad = set()
    for p in map(Path, paths):
        bad |= {s.parent for s in p.rglob("summary.json")
                if not (s.parent / "eval_meta.json").is_file()}
        bad |= {h.parent for h in p.rglob(".hydra") if h.is_dir()
                and not (h.parent / "summary.json").is_file()
                and not (h.parent / "result.json").is_file()}
    return sorted(bad)


def load_run(run_dir: Path) -> dict:
    """One flat record: method, protocol, metric columns (display units), runtimes."""
    from eval.layout import LayoutError, read_json_object

    summary_path, meta_path = run_dir / "summary.json", run_dir / "eval_meta.json"
    summary = read_json_object(summary_path)
    meta = read_json_object(meta_path) if meta_path.is_file() else {}
    if not summary:
        raise LayoutError(f"{summary_path}: no channel scored (an evaluation of 0 images); "
                          "re-run gspi-eval, which now refuses such a prediction folder")
    for ch, scores in summary.items():  # a NaN or a string must not print as "--" (not modelled)
        if not isinstance(scores, dict):
            raise LayoutError(f"{summary_path}: {ch} must be an object {{psnr, ssim, lpips}}, got {scores!r}")
        for metric, value in scores.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
                raise LayoutError(f"{summary_path}: {ch}.{metric} must be a number, got {value!r}")
    if not isinstance(meta.get("protocol", {}), dict):
        raise LayoutError(f"{meta_path}: protocol must be an object {{name, version}}")
    rec = {"method": meta.get("method", run_dir.name), "run": str(run_dir),
           "protocol": f"{meta.get('protocol', {}).get('name')}"
                       f" v{meta.get('protocol', {}).get('version')}",
           "protocol_config": recorded_protocol(meta), "counts": meta.get("counts") or {},
           "data": meta.get("data"), "scenes": tuple(sorted(meta.get("scenes") or []))}
    for metric, _, scale, _ in METRICS:
        for ch in CHANNELS:
            value = summary.get(ch, {}).get(metric)
            rec[f"{metric}/{ch}"] = None if value is None else scale * float(value)
    runtime = meta.get("runtime_min", {}) or {}
    rec["runtime/material"] = runtime.get("material")
    rec["runtime/end_to_end"] = runtime.get("end_to_end")
    return rec


def check_compatible(records: list[dict]) -> None:
    """Refuse to average runs of one method scored on different datasets or scene sets (the
    error names the runs); runs without a recorded dataset/scenes are not compared."""
    by_method: dict[str, list[dict]] = {}
    for rec in records:
        by_method.setdefault(rec["method"], []).append(rec)
    for method, recs in by_method.items():
        for key, what in (("data", "ground-truth datasets"), ("scenes", "scene sets")):
            values = {rec.get(key) for rec in recs if rec.get(key)}
            if len(values) > 1:
                lines = [f"{rec['run']}: {rec.get(key)}" for rec in recs]
                raise ValueError(f"method {method!r}: its runs were scored on different {what}, "
                                 "so their mean would mix them:\n  " + "\n  ".join(lines))


def build_table1(records: list[dict]) -> pd.DataFrame:
    """Methods x columns, runs of one method averaged; refuses mixed protocols (any key of
    the resolved protocol) and runs of one method on different data or scene sets."""
    check_one_protocol({rec["run"]: rec.get("protocol_config") or {"name": rec["protocol"]}
                        for rec in records})
    check_compatible(records)
    frame = pd.DataFrame(records)
    cols = [f"{m}/{c}" for m, *_ in METRICS for c in CHANNELS] + \
        ["runtime/material", "runtime/end_to_end"]
    table = frame.groupby("method", sort=False)[cols].mean()
    table.attrs["protocol"] = describe_protocol(records[0].get("protocol_config") or {})
    table.attrs["counts"] = describe_counts(sum_counts([r.get("counts") for r in records]))
    table.attrs["incomplete"] = []
    return table


def rank_marks(table: pd.DataFrame) -> pd.DataFrame:
    """Per cell: 1 = best, 2 = second best in its column, 0 otherwise."""
    marks = pd.DataFrame(0, index=table.index, columns=table.columns)
    for col in table.columns:
        if col == "runtime/end_to_end":
            continue  # ranked together with the material time
        higher = any(col.startswith(m) and hi for m, _, _, hi in METRICS)
        values = table[col].dropna()
        values = values[values.map(lambda v: math.isfinite(v) or higher)]
        order = values.sort_values(ascending=not higher).index.tolist()
        for rank, method in enumerate(order[:2], start=1):
            marks.loc[method, col] = rank
    return marks


def _fmt(value, col: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "--"
    if math.isinf(value):
        return "inf"
    return f"{value:.1f}" if col.startswith("runtime") else f"{value:.2f}"


def _runtime_cell(row) -> str:
    """"material (end-to-end)"; a system whose material time cannot be split from its geometry
    (one joint run, docs/BASELINES.md) shows its end-to-end time as "T total only"."""
    mat, e2e = row["runtime/material"], row["runtime/end_to_end"]
    e2e_ok = e2e is not None and not (isinstance(e2e, float) and math.isnan(e2e))
    if mat is None or (isinstance(mat, float) and math.isnan(mat)):
        return f"{_fmt(e2e, 'runtime')} total only" if e2e_ok else "--"
    return _fmt(mat, "runtime") + (f" ({_fmt(e2e, 'runtime')})" if e2e_ok else "")


def _cells(table: pd.DataFrame, marks: pd.DataFrame, style: str) -> list[list[str]]:
    best = {"md": ("**{}**", "<u>{}</u>"),
            "tex": (r"\cellcolor{{BaselineBestCell}}\textbf{{{}}}",
                    r"\cellcolor{{BaselineSecondCell}}{}")}[style]
    rows = []
    for method, row in table.iterrows():
        cells = [str(method)]
        for m, *_ in METRICS:
            for c in CHANNELS:
                col = f"{m}/{c}"
                text, mark = _fmt(row[col], col), marks.loc[method, col]
                cells.append(best[mark - 1].format(text) if mark and text != "--" else text)
        rt, mark = _runtime_cell(row), marks.loc[method, "runtime/material"]
        cells.append(best[mark - 1].format(rt) if mark and rt != "--" else rt)
        rows.append(cells)
    return rows


def to_markdown(table: pd.DataFrame) -> str:
    marks = rank_marks(table)
    head = ["Method"] + [f"{label} {c}" for _, label, *_ in METRICS for c in CHANNELS] + \
        ["Runtime (min) material (end-to-end)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in _cells(table, marks, "md")]
    lines.append(f"\nProtocol: {table.attrs.get('protocol')}. Best **bold**, second <u>underlined</u>;"
                 " -- = channel not modelled.")
    lines += [f"\n{line}" for line in footer_extra(table)]
    return "\n".join(lines) + "\n"


def footer_extra(table: pd.DataFrame) -> list[str]:
    """Image counts per channel and the incomplete folders left out."""
    lines = [f"{table.attrs['counts']}."] if table.attrs.get("counts") else []
    if table.attrs.get("incomplete"):
        lines.append("Incomplete gspi-eval folder(s) left out (killed before eval_meta.json): "
                     + ", ".join(map(str, table.attrs["incomplete"])))
    return lines


def _latex_label(label: str) -> str:
    return label.replace("%", r"\%").replace("↑", r"$\uparrow$").replace("↓", r"$\downarrow$")


def to_latex(table: pd.DataFrame) -> str:
    marks = rank_marks(table)
    groups = " & ".join(rf"\multicolumn{{4}}{{c}}{{{_latex_label(label)}}}" for _, label, *_ in METRICS)
    sub = " & ".join(CHANNELS * 3)
    body = "\n".join(" & ".join(r).replace("%", r"\%") + r" \\" for r in _cells(table, marks, "tex"))
    return (f"% {LATEX_COLORS.splitlines()[0]}\n% {LATEX_COLORS.splitlines()[1]}\n"
            f"% protocol: {table.attrs.get('protocol')}\n"
            + "".join(f"% {line}\n" for line in footer_extra(table)) +
            r"\begin{tabular}{l cccc cccc cccc c}" "\n" r"\toprule" "\n"
            rf"\multirow{{2}}{{*}}{{Method}} & {groups} & \multirow{{2}}{{*}}{{\makecell{{Runtime\\(min)}}}} \\"
            "\n" r"\cmidrule(lr){2-5} \cmidrule(lr){6-9} \cmidrule(lr){10-13}" "\n"
            f" & {sub} & \\\\\n" r"\midrule" "\n" f"{body}\n" r"\bottomrule" "\n" r"\end{tabular}" "\n")


def write_tables(table: pd.DataFrame, out_dir: Path, stem: str = "table1") -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"md": out_dir / f"{stem}.md", "tex": out_dir / f"{stem}.tex",
             "csv": out_dir / f"{stem}.csv"}
    for kind, text in (("md", to_markdown(table)), ("tex", to_latex(table)),
                       ("csv", table.to_csv())):
        write_text_atomic(paths[kind], text)
    return paths


def is_sweep(paths: list[str | Path]) -> bool:
    """True when the folders hold gspi-run records, or Hydra job folders (even all killed) and
    no complete gspi-eval folder: a killed gspi-eval folder next to complete ones does not
    turn them into a sweep (it is listed as incomplete in the table's footer)."""
    from eval.sweep import find_records

    records, unfinished = find_records(paths)
    if records:
        return True
    has_eval = any((s.parent / "eval_meta.json").is_file()
                   for p in paths if Path(p).exists() for s in Path(p).rglob("summary.json"))
    return bool(unfinished) and not has_eval


def run_sweep(cfg) -> dict:
    """Tables 1-3 (those with rows, or `cfg.table`) of a sweep -> files; returns the tables."""
    from eval.sweep import TABLES, load_sweep
    from eval.tables_render import to_markdown, write_sweep_table
    from eval.tables_sweep import TABLE_SPECS, build_sweep_table

    chosen = cfg.get("table")
    if chosen is not None and chosen not in TABLES:
        raise ValueError(f"table={chosen!r}: allowed values are {', '.join(TABLES)} or null")
    names = (chosen,) if chosen else TABLES
    sweep = load_sweep(list(cfg.runs), tables=names)
    boot = dict(cfg.get("bootstrap") or {})
    built = {n: build_sweep_table(sweep, TABLE_SPECS[n], bootstrap=boot) for n in names}
    built = {n: t for n, t in built.items() if t is not None}
    if not built:
        failed = "; ".join(f"{r.run_dir}: {r.error}" for r in sweep.failed)
        raise ValueError(f"no complete run record of {', '.join(names)} below "
                         f"{', '.join(map(str, cfg.runs))} ({len(sweep.failed)} failed"
                         f"{': ' + failed if failed else ''}; {len(sweep.unfinished)} job "
                         "folder(s) without result.json)")
    for table in built.values():
        write_sweep_table(table, sweep, Path(cfg.out))
        print(to_markdown(table, sweep))
    return built


def run(cfg):
    """Sweep folders -> Tables 1-3 (dict of SweepTable); gspi-eval folders -> Table 1 frame."""
    runs = list(cfg.runs) if cfg.runs else []
    if not runs:
        raise ValueError("give evaluated run folders: gspi-table DIR [DIR ...] or runs=[...]")
    if is_sweep(runs):
        return run_sweep(cfg)
    table = build_table1([load_run(r) for r in find_runs(runs)])
    table.attrs["incomplete"] = find_incomplete(runs)
    for folder in table.attrs["incomplete"]:
        log.warning("%s: incomplete gspi-eval folder (killed?), left out of the table", folder)
    paths = write_tables(table, Path(cfg.out))
    print(paths["md"].read_text())
    return table


def positional_to_overrides(argv: list[str]) -> list[str]:
    """Let `gspi-table DIR DIR` mean `gspi-table runs=[DIR,DIR]` (Hydra takes key=value only)."""
    # An existing path is a folder even with "=" in it (Hydra's sweep job folders: method=gspi).
    from eval.argv import needs_quoting, quote_path_overrides, quote_value

    dirs = [a for a in argv if not a.startswith("-") and ("=" not in a or Path(a).exists())]
    rest = quote_path_overrides([a for a in argv if a not in dirs], ("out",))
    quoted = ",".join(quote_value(d) if needs_quoting(d) else d for d in dirs)  # any folder name: = , ' spaces, non-ASCII
    return rest + ([f"runs=[{quoted}]"] if dirs else [])


def main() -> None:
    import hydra

    from eval.config import CONF_DIR

    sys.argv = [sys.argv[0]] + positional_to_overrides(sys.argv[1:])

    @hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="gspi_table")
    def _main(cfg) -> None:
        run(cfg)

    _main()


if __name__ == "__main__":
    main()
