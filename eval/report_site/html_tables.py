"""Sweep tables (`eval.tables.build.SweepTable`) as sortable HTML tables with their footer.

Cells read "mean ± SE" like the Markdown tables; each cell carries its mean in `data-v` so the
page sorts by value. Best and second best of a column (`SweepTable.marks`) get the classes
`best` (red cell, bold) and `second` (yellow cell, underlined), the paper's colours.
"""
from __future__ import annotations

import math
from html import escape

import pandas as pd

from eval.sweep import Sweep
from eval.tables.render import METRIC_LABELS, footer_lines
from eval.tables.build import SweepTable

MARK_CLASSES = {1: "best", 2: "second"}


def _number(value: float, digits: int) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "--"
    return "inf" if math.isinf(value) else f"{value:.{digits}f}"


def _data_v(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return "1e308" if math.isinf(value) and value > 0 else repr(float(value))


def _header(table: SweepTable) -> list[str]:
    cols = table.spec.columns
    multi = len({c.channel for c in cols if c.measure != "runtime"}) > 1
    heads = []
    for c in cols:
        if c.measure == "runtime":
            heads.append(f"Runtime (min) {c.channel.replace('_', '-')}")
        else:
            heads.append(METRIC_LABELS[c.metric] + (f" {c.channel}" if multi else ""))
    return [table.spec.row_header] + heads + ["n", "Δ PSNR vs reference"]


def sweep_table_html(table: SweepTable, sweep: Sweep) -> str:
    """One `<table class="metrics">` (one row per table row) and its footer list."""
    cols = table.spec.columns
    head = "".join(f"<th>{escape(h)}</th>" for h in _header(table))
    rows = []
    for label in table.labels:
        cells = [f"<td data-v=\"{escape(label)}\">{escape(label)}</td>"]
        for c in cols:
            mean, sem = table.mean.loc[label, c.key], table.sem.loc[label, c.key]
            digits = 1 if c.metric == "minutes" else 2
            text = _number(mean, digits)
            if text != "--" and not math.isnan(sem):
                text += f" ± {_number(sem, digits)}"
            mark = MARK_CLASSES.get(int(table.marks.loc[label, c.key]), "") if text != "--" else ""
            cls = f" class=\"{mark}\"" if mark else ""
            cells.append(f"<td{cls} data-v=\"{_data_v(mean)}\">{escape(text)}</td>")
        n = int(table.count.loc[label, table.spec.delta.key])
        cells.append(f"<td data-v=\"{n}\">{n}</td>")
        d = table.delta.loc[label]
        if label == table.reference:
            cells.append("<td data-v=\"0\">reference</td>")
        elif math.isnan(d["mean"]):
            cells.append("<td data-v=\"\">--</td>")
        else:
            cells.append(f"<td data-v=\"{d['mean']!r}\">{d['mean']:+.2f} "
                         f"[{d['lo']:+.2f}, {d['hi']:+.2f}]</td>")
        rows.append("<tr>" + "".join(cells) + "</tr>")
    foot = "".join(f"<li>{escape(line)}</li>" for line in footer_lines(table, sweep, "md")
                   ).replace("**bold**", "bold").replace("&lt;u&gt;underlined&lt;/u&gt;",
                                                         "underlined")
    return (f"<h3>{escape(table.spec.title)}</h3>\n<table class=\"metrics\" "
            f"id=\"{table.spec.name}\"><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}"
            f"</tbody></table>\n<ul class=\"footer\">{foot}</ul>")


def frame_html(frame: pd.DataFrame, *, index_name: str, digits: int = 2, table_id: str = "") -> str:
    """A numeric DataFrame (rows x columns) as a sortable table; NaN shows "--"."""
    head = f"<th>{escape(index_name)}</th>" + "".join(f"<th>{escape(str(c))}</th>"
                                                      for c in frame.columns)
    rows = []
    for index, row in frame.iterrows():
        cells = [f"<td data-v=\"{escape(str(index))}\">{escape(str(index))}</td>"]
        cells += [f"<td data-v=\"{_data_v(v)}\">{_number(v, digits)}</td>" for v in row]
        rows.append("<tr>" + "".join(cells) + "</tr>")
    ident = f" id=\"{table_id}\"" if table_id else ""
    return (f"<table class=\"metrics\"{ident}><thead><tr>{head}</tr></thead>"
            f"<tbody>{''.join(rows)}</tbody></table>")
