"""The results store: every committed score of a product table, in one layout.

    results/<table>/<scale>/<run>/      one run's record (what its table reads)
    results/table1/cpu/method=<m>/      the demo's gspi-run jobs (result.json, eval/, eval_aligned_clamp/, ...)
    results/table2/cpu/<variant>_s<seed>/scores.json   gspi-points-eval of one Stage II training
    results/table3/cpu/<job>/           gspi-reproduce table=3's gspi-run jobs
    results/heldout/cpu/<model>/scores.json             a shipped model on the held-out pool scenes
    results/shipping/cpu/<model>/scores.json            a retired shipping-rule candidate's record (eval.tables.cards)
    results/speed/cpu/pipeline_<preset>.json            make bench's GS-PI vs joint IR material time (bench_pipeline)
    results/speed/cpu/demo.json                         make bench's `make demo` time, step by step (bench_demo)
    results/speed/cpu/budget_<data>.json                a speed budget's cost in quality (benchmarks/budget_quality.py)

A table's reproduce file (conf/reproduce/<table>_<scale>.yaml) names its folder as ``scores_dir``;
``make results`` (gspi.publish.docs) reads them here. Studies keep theirs in experiments/<study>/.
"""
from __future__ import annotations

from pathlib import Path

from gspi.repo import REPO

RESULTS = REPO / "results"


def table_folder(table: str, scale: str = "cpu") -> Path:
    """``results/<table>/<scale>``: the runs of one table at one scale."""
    return RESULTS / table / scale
