"""A built sweep table -> Markdown, LaTeX (the paper's cell colours) and CSV; atomic writes.

Markdown and LaTeX cells read "mean ± SE"; the best mean of a column is bold (LaTeX: red
cell), the second underlined (LaTeX: yellow cell), as in the paper. CSV keeps mean, sem and n
in separate columns. Footers state what a cell averages, the Δ definition, the protocol, and
every failed, unfinished, duplicate or superseded job.
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from eval.common.atomic import write_text_atomic
from eval.sweep import Sweep
from eval.tables.build import Column, SweepTable, rows_with_failed_jobs

LATEX_COLORS = (r"\definecolor{BaselineBestCell}{RGB}{255,235,238}",
                r"\definecolor{BaselineSecondCell}{RGB}{255,249,196}")
METRIC_LABELS = {"psnr": "PSNR↑", "ssim": "SSIM(%)↑", "lpips": "LPIPS(%)↓"}
MARKS = {"md": ("**{}**", "<u>{}</u>"),
         "tex": (r"\cellcolor{{BaselineBestCell}}\textbf{{{}}}",
                 r"\cellcolor{{BaselineSecondCell}}{}")}


def _num(value: float, digits: int) -> str:
    if value is None or math.isnan(value):
        return "--"
    return "inf" if math.isinf(value) else f"{value:.{digits}f}"


RESOURCE_MEASURES = ("runtime", "memory")  # shown after the metric columns, never ranked


def _digits(col: Column) -> int:
    return {"minutes": 1, "mb": 0}.get(col.metric, 2)


def _metric_cols(table: SweepTable) -> list[Column]:
    return [c for c in table.spec.columns if c.measure not in RESOURCE_MEASURES]


def _cell(table: SweepTable, label: str, col: Column, style: str) -> str:
    mean, sem = table.mean.loc[label, col.key], table.sem.loc[label, col.key]
    text = _num(mean, _digits(col))
    if text != "--" and not math.isnan(sem):
        pm = " ± " if style == "md" else r"{\scriptsize$\pm$"
        text += pm + _num(sem, _digits(col)) + ("" if style == "md" else "}")
    mark = table.marks.loc[label, col.key]
    return MARKS[style][mark - 1].format(text) if mark and text != "--" else text


def _delta_cell(table: SweepTable, label: str, style: str) -> str:
    if label == table.reference:
        return "reference"
    d = table.delta.loc[label]
    if math.isnan(d["mean"]):
        return "--"
    text = f"{d['mean']:+.2f} [{d['lo']:+.2f}, {d['hi']:+.2f}]"
    return text if style == "md" else f"${text}$"


def _row_cells(table: SweepTable, label: str, style: str) -> list[str]:
    cells = [_cell(table, label, c, style) for c in _metric_cols(table)]
    runtime = [c for c in table.spec.columns if c.measure == "runtime"]
    if runtime:
        material, e2e = (_cell(table, label, c, style) for c in runtime)
        if material == "--" and e2e != "--":  # one joint run: material not separable (docs/BASELINES.md)
            cells.append(f"{e2e} total only")
        else:
            cells.append(material + (f" ({e2e})" if e2e != "--" and material != "--" else ""))
    cells += [_cell(table, label, c, style) for c in table.spec.columns if c.measure == "memory"]
    n = int(table.count.loc[label, table.spec.delta.key])
    return cells + [str(n), _delta_cell(table, label, style)]


def _headers(table: SweepTable) -> list[str]:
    multi_channel = len({c.channel for c in _metric_cols(table)}) > 1
    heads = [METRIC_LABELS[c.metric] + (f" {c.channel}" if multi_channel else "") for c in _metric_cols(table)]
    if any(c.measure == "runtime" for c in table.spec.columns):
        heads.append("Runtime (min) material (end-to-end)")
    if any(c.measure == "memory" for c in table.spec.columns):
        heads.append("Peak RSS (MB)")
    delta = table.spec.delta
    what = f"PSNR {delta.channel}" if multi_channel else "PSNR"
    ref = table.reference or "reference (none)"
    ci = int(round(100 * table.bootstrap.get("confidence", 0.95)))
    return [table.spec.row_header] + heads + ["n", f"Δ {what} vs {ref} [{ci}% CI]"]


def footer_lines(table: SweepTable, sweep: Sweep, style: str = "md") -> list[str]:
    """What a cell is, how Δ is computed, and every job left out (one line each)."""
    b = table.bootstrap
    marks = {"md": "Best **bold**, second <u>underlined</u>",
             "tex": "Best: red cell, bold; second: yellow cell"}[style]
    lines = [f"Cells: mean ± standard error over n (scene, seed) units; {table.spec.averaging}. "
             f"SSIM and LPIPS in %. {marks}; -- = not available."]
    if table.reference is not None:
        lines.append(f"Δ: mean paired difference to {table.reference} over the (scene, seed) "
                     f"units both rows have, {int(round(100 * b['confidence']))}% percentile "
                     f"bootstrap interval ({b['n']} resamples, seed {b['seed']}).")
    lines.append(f"Protocol: {table.protocol or '--'}. Data: {table.data or '--'}.")
    if table.counts:
        lines.append(f"{table.counts}.")
    lines += table.notes
    short = rows_with_failed_jobs(sweep, table.spec.name, table.rows)
    if short:
        lines.append(f"rows with failed or unfinished jobs: {'; '.join(short)}")
    mine = [r for r in sweep.failed if r.table == table.spec.name]
    lines += [f"failed job: {r.run_dir} ({r.method}, {r.ablation}, seed {r.seed}): {r.error}"
              for r in mine]
    lines += [f"failed job superseded by a complete rerun: {r.run_dir}"
              for r in sweep.superseded if r.table == table.spec.name]
    if sweep.unfinished:
        lines.append(f"{len(sweep.unfinished)} job folder(s) without result.json (killed or "
                     f"still running) ignored: {', '.join(map(str, sweep.unfinished))}")
    lines += sweep.notes
    return lines


def to_markdown(table: SweepTable, sweep: Sweep) -> str:
    head = _headers(table)
    lines = [f"### {table.spec.title}", "", "| " + " | ".join(head) + " |",
             "|" + "---|" * len(head)]
    lines += ["| " + " | ".join([label] + _row_cells(table, label, "md")) + " |"
              for label in table.labels]
    return "\n".join(lines + [""] + [f"- {line}" for line in footer_lines(table, sweep)]) + "\n"


def _tex_escape(text: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"),
                 ("#", r"\#"), ("↑", r"$\uparrow$"), ("↓", r"$\downarrow$"),
                 ("Δ", r"$\Delta$")):
        text = text.replace(a, b)
    return text


def to_latex(table: SweepTable, sweep: Sweep) -> str:
    head = _headers(table)
    ncols = len(head) - 1
    body = []
    for label in table.labels:
        if label == table.reference and len(table.labels) > 1:
            body.append(r"\midrule")
        name = rf"\textbf{{{_tex_escape(label)}}}" if label == table.reference else \
            _tex_escape(label)
        cells = [c.replace(" ± ", r"$\pm$") for c in _row_cells(table, label, "tex")]
        body.append(" & ".join([name] + [c.replace("%", r"\%") for c in cells]) + r" \\")
    comments = [f"% {line}" for line in (*LATEX_COLORS, *footer_lines(table, sweep, "tex"))]
    return "\n".join(comments + [
        rf"\begin{{tabular}}{{l {'c' * ncols}}}", r"\toprule", *_latex_header(table, head),
        r"\midrule", *body, r"\bottomrule", r"\end{tabular}"]) + "\n"


def _latex_header(table: SweepTable, head: list[str]) -> list[str]:
    """One header line, or for Table 1 the paper's two: metric groups over channel names."""
    cols = _metric_cols(table)
    channels = list(dict.fromkeys(c.channel for c in cols))
    if len(channels) == 1:
        return [" & ".join(_tex_escape(h) for h in head) + r" \\"]
    metrics = list(dict.fromkeys(c.metric for c in cols))
    k, tail = len(channels), head[1 + len(cols):]
    groups = " & ".join(rf"\multicolumn{{{k}}}{{c}}{{{_tex_escape(METRIC_LABELS[m])}}}"
                        for m in metrics)
    rules = " ".join(rf"\cmidrule(lr){{{2 + i * k}-{1 + (i + 1) * k}}}"
                     for i in range(len(metrics)))
    multirow = " & ".join(rf"\multirow{{2}}{{*}}{{{_tex_escape(h)}}}" for h in tail)
    return [rf"\multirow{{2}}{{*}}{{{_tex_escape(head[0])}}} & {groups} & {multirow} \\", rules,
            " & " + " & ".join(channels * len(metrics)) + " & " * len(tail) + r" \\"]


def to_csv(table: SweepTable) -> str:
    """One line per row: label, method, ablation, then <metric>/<channel>/{mean,sem,n}, Δ."""
    out = pd.DataFrame({"label": table.labels, "method": [r[0] for r in table.rows],
                        "ablation": [r[1] for r in table.rows]})
    for col in table.spec.columns:
        for stat, frame in (("mean", table.mean), ("sem", table.sem), ("n", table.count)):
            out[f"{col.key}/{stat}"] = frame[col.key].to_numpy()
    for stat in ("mean", "lo", "hi", "n_pairs"):
        out[f"delta_{table.spec.delta.key}/{stat}"] = table.delta[stat].to_numpy()
    return out.to_csv(index=False)


def per_scene_markdown(table: SweepTable) -> str:
    d = table.spec.delta
    what = "avg of albedo, roughness, metallic" if d.channel == "avg" else d.channel
    frame = table.per_scene
    head = ["Scene"] + list(frame.columns)
    lines = [f"### {table.spec.title}: per scene, PSNR↑ ({what}), mean over seeds", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join([str(scene)] + [_num(v, 2) for v in row]) + " |"
              for scene, row in frame.iterrows()]
    return "\n".join(lines) + "\n"


def write_sweep_table(table: SweepTable, sweep: Sweep, out_dir: Path) -> dict[str, Path]:
    """<out>/<table>.{md,tex,csv} and <table>_per_scene.{md,csv}, each written atomically."""
    stem = table.spec.name
    texts = {f"{stem}.md": to_markdown(table, sweep), f"{stem}.tex": to_latex(table, sweep),
             f"{stem}.csv": to_csv(table), f"{stem}_per_scene.md": per_scene_markdown(table),
             f"{stem}_per_scene.csv": table.per_scene.to_csv()}
    paths = {}
    for name, text in texts.items():
        write_text_atomic(Path(out_dir) / name, text)
        paths[name] = Path(out_dir) / name
    return paths
