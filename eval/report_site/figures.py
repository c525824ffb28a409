"""The paper's figures from the report's data, as PNG and PDF (matplotlib).

* ``qualitative``: per scene a block, per method a column: the relit image (first held-out
  environment) over albedo, roughness and metallic; a crossed box where the method has no
  such image (a channel it does not model, a missing prediction).
* ``ablation_stage2`` / ``ablation_stage3``: the same grid over the Table 2 / Table 3 variants,
  from each variant's material predictions (a gspi-run of a Stage II variant predicts through
  Stage III too; its Table 2 score is on the point cloud, these images are the final maps).
* ``teaser_scatter``: relight PSNR against speed = 1 / runtime (end-to-end minutes when known,
  else material minutes), one point per Table 1 row, log speed axis.

Images are exactly the report's (eval.report_site.panels), so a figure and the page agree.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from eval.report_site.panels import ViewPanels

CHANNEL_ROWS = ("albedo", "roughness", "metallic")
SHORT = {"albedo": "albedo", "roughness": "rough.", "metallic": "metal."}


def _crossed(ax, note: str = "") -> None:
    ax.plot([0, 1], [0, 1], color="0.6", lw=0.8, transform=ax.transAxes)
    ax.plot([0, 1], [1, 0], color="0.6", lw=0.8, transform=ax.transAxes)
    for side in ax.spines.values():
        side.set_visible(True)
        side.set_color("0.6")
    if note:
        ax.text(0.5, 0.5, note, ha="center", va="center", fontsize=5, color="#a00",
                transform=ax.transAxes, wrap=True)


def _show(ax, image) -> None:
    ax.set_xticks([])
    ax.set_yticks([])
    for side in ax.spines.values():
        side.set_visible(False)
    if image is None:
        _crossed(ax)
        return
    ax.imshow(np.clip(image, 0, 1), interpolation="nearest")


def grid_figure(blocks: list[tuple[str, ViewPanels, str]], labels: list[str], title: str):
    """blocks: (scene name, its ViewPanels, relit key); columns: GT + `labels`."""
    import matplotlib.pyplot as plt
    from matplotlib.gridspec import GridSpec

    cols = ["GT"] + labels
    fig = plt.figure(figsize=(1.5 * len(cols), 2.1 * len(blocks) + 0.4))
    outer = GridSpec(len(blocks), len(cols), figure=fig, hspace=0.25, wspace=0.08)
    for b, (scene, vp, relit) in enumerate(blocks):
        for c, label in enumerate(cols):
            inner = outer[b, c].subgridspec(2, 3, height_ratios=[3, 1], hspace=0.05, wspace=0.05)
            if label == "GT":
                images = {k: vp.gt.get(k) for k in (relit, *CHANNEL_ROWS)}
            else:
                panels = vp.jobs.get(label, {})
                images = {k: getattr(panels.get(k), "image", None) for k in (relit, *CHANNEL_ROWS)}
            top = fig.add_subplot(inner[0, :])
            _show(top, images[relit])
            if b == 0:
                top.set_title(label, fontsize=7)
            if c == 0:
                top.set_ylabel(f"{scene}\n{relit.replace('relit:', 'relit ')}", fontsize=6)
            for k, ch in enumerate(CHANNEL_ROWS):
                ax = fig.add_subplot(inner[1, k])
                _show(ax, images[ch])
                if b == len(blocks) - 1:
                    ax.set_xlabel(SHORT[ch], fontsize=5)
    fig.suptitle(title, fontsize=8)
    return fig


def scatter_figure(table) -> "object":
    """Relight PSNR vs speed (1 / minutes) of the Table 1 rows."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.2, 3.2))
    for label in table.labels:
        psnr = table.mean.loc[label, "psnr/relight"]
        minutes = table.mean.loc[label, "minutes/end_to_end"]
        if minutes is None or math.isnan(minutes) or minutes <= 0:
            minutes = table.mean.loc[label, "minutes/material"]
        if any(v is None or math.isnan(v) or not math.isfinite(v) for v in (psnr, minutes)) or minutes <= 0:
            continue
        ax.scatter(1.0 / minutes, psnr, s=40, color="#c62828" if label == table.reference else "#1565c0")
        ax.annotate(label, (1.0 / minutes, psnr), fontsize=7, xytext=(4, 4),
                    textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("speed = 1 / runtime (1/min; end-to-end when known)", fontsize=8)
    ax.set_ylabel("relight PSNR (dB)", fontsize=8)
    ax.set_title("Quality vs speed (Table 1)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig


def _save(fig, out_dir: Path, stem: str) -> list[Path]:
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{stem}.png", out_dir / f"{stem}.pdf"]
    fig.savefig(paths[0], dpi=150, bbox_inches="tight")
    fig.savefig(paths[1], bbox_inches="tight")
    plt.close(fig)
    return paths


def write_figures(out_dir: Path, jobs, tables: dict, first_views: dict[str, tuple],
                  *, max_scenes: int = 4) -> list[Path]:
    """Write every figure the data allows; returns the paths (PNG and PDF of each).

    Args:
        jobs: the shown jobs (eval.report_site.scene_page.shown_jobs), in row order.
        tables: {table name: SweepTable}.
        first_views: scene -> (ViewPanels of its first view, environment names).
    """
    import matplotlib

    matplotlib.use("Agg")
    scenes = sorted(first_views)[:max_scenes]
    blocks = [(s, first_views[s][0], f"relit:{first_views[s][1][0]}") for s in scenes
              if first_views[s][1]]
    written = []
    specs = (("qualitative", "table1", "Qualitative comparison (first test view)"),
             ("ablation_stage2", "table2", "Qualitative ablation of Stage II"),
             ("ablation_stage3", "table3", "Qualitative ablation of Stage III distillation"))
    for stem, table, title in specs:
        labels = [j.label for j in jobs if j.table == table and j.predictions is not None]
        if blocks and labels:
            written += _save(grid_figure(blocks, labels, title), out_dir, stem)
    if "table1" in tables:
        written += _save(scatter_figure(tables["table1"]), out_dir, "teaser_scatter")
    return written
