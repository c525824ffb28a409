"""Tables 1 and 3 as steps (``gspi.reproduce.plan``): the benchmark data -> the table's gspi-run
sweep (``+experiment=<name>``; rerunning it skips finished jobs) -> each job's gspi-eval scores
committed -> the table (gspi-table over the committed scores).

Config: conf/reproduce/table{1,3}_<scale>.yaml. The committed scores of a job are its gspi-eval
folder's ``summary.json``, ``per_view.csv`` and ``eval_meta.json`` (paths made portable), which
``gspi-table`` reads as a plain evaluation folder.
"""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Mapping

from gspi.reproduce.plan import Step
from gspi.reproduce.portable import portable
from gspi.reproduce.table2 import tool

EVAL_FILES = ("per_view.csv", "eval_meta.json", "summary.json")  # summary.json last: the folder is complete


def commit_eval_folders(runs: Path, scores_dir: Path, roots: Mapping[str, Path]) -> list[Path]:
    """Copies every ``<runs>/<job>/eval`` folder's scores to ``<scores_dir>/<job>/`` (portable JSON)."""
    import json

    written = []
    for summary in sorted(runs.glob("*/eval/summary.json")):
        job = summary.parent.parent.name
        dst = scores_dir / job
        if dst.exists():
            shutil.rmtree(dst)
        dst.mkdir(parents=True)
        for name in EVAL_FILES:
            src = summary.parent / name
            if name.endswith(".json"):
                (dst / name).write_text(json.dumps(portable(json.loads(src.read_text()), roots), indent=1,
                                                   sort_keys=True) + "\n")
            else:
                shutil.copyfile(src, dst / name)
        written.append(dst)
    return written


def sweep_table_steps(cfg: Mapping[str, Any], *, root: Path) -> list[Step]:
    """Data, the sweep, the committed scores and the table of Table 1 or 3 at ``cfg``'s scale."""
    work = (root / cfg["work"]).resolve()
    data, runs = work / "data", work / "runs"
    scores_dir, tables_dir = root / cfg["scores_dir"], root / cfg["tables_dir"]
    name = f"table{cfg['table']}"
    done = work / ".done"
    steps = [
        Step("data", done / "data", [tool("gspi-data"), f"preset={cfg['preset']}", f"out={data}", "seed=0",
                                     *cfg["data_overrides"]]),
        Step(f"{name}: sweep", done / "sweep", [tool("gspi-run"), "-m", f"data={data}", f"out={runs}",
                                                f"+experiment={cfg['experiment']}", *cfg["run_overrides"]]),
        Step(f"{name}: commit scores", done / "scores",
             action=lambda: commit_eval_folders(runs, scores_dir, {"<work>": work, "<repo>": root})),
    ]
    if any(scores_dir.glob("*/summary.json")):
        steps = []  # committed scores stand (written all at once after the sweep): nothing to recompute
    table = Step("table", tables_dir / ".built", [tool("gspi-table"), str(scores_dir), f"out={tables_dir}",
                                                  f"table={name}"])
    table.done.unlink(missing_ok=True)
    for step in steps:
        step.aliases = {str(work): "<work>"}
    return steps + [table]
