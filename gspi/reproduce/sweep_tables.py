"""Tables 1 and 3 as steps (``gspi.reproduce.plan``): the benchmark data -> the table's gspi-run
sweep (``+experiment=<name>``; rerunning it skips finished jobs) -> each job's gspi-eval scores
committed -> the table (gspi-table over the committed scores).

Config: conf/reproduce/table{1,3}_<scale>.yaml. The committed scores of a job are its record
(``result.json``), its gspi-eval summary and metadata and its scenes' ``meta.json`` (paths made
portable; ``commit_sweep_records``), which ``gspi-table`` reads as a sweep (results/table1/cpu/ holds
Table 1's).
"""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any, Collection, Mapping

from gspi.reproduce.costs import cost, preset_scene_count, recorded_job_seconds
from gspi.reproduce.plan import Step
from eval.portable import portable
from gspi.reproduce.table2 import tool

# what a job folder's record is made of (gspi-table reads a sweep of such folders; results/table1/cpu/README.md)
RECORD_FILES = ("result.json", "eval/eval_meta.json", "eval/summary.json", "points_eval/points_summary.json")


def commit_sweep_records(runs: Path, scores_dir: Path, roots: Mapping[str, Path],
                         seeds: Collection[int] | None = None) -> list[Path]:
    """Copies every finished job of the sweep ``runs`` (its ``result.json``; of ``seeds`` only, when
    given) to ``<scores_dir>/<job>/``: the record, its gspi-eval summary and metadata, Table 2's
    points summary and each scene's ``meta.json`` (runtimes), JSON with portable paths; no
    predictions, no images."""
    import json

    written = []
    for record in sorted(runs.glob("*/result.json")):
        job = record.parent
        if seeds is not None and int(json.loads(record.read_text())["seed"]) not in seeds:
            continue
        dst = scores_dir / job.name
        if dst.exists():
            shutil.rmtree(dst)
        files = [job / f for f in RECORD_FILES if (job / f).is_file()] + sorted(job.glob("predictions/*/meta.json"))
        for src in sorted(files, key=lambda f: f.name == "result.json"):  # the record last: the folder is complete
            out = dst / src.relative_to(job)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(portable(json.loads(src.read_text()), roots), indent=1, sort_keys=True) + "\n")
        written.append(dst)
    return written


def committed_seeds(scores_dir: Path) -> set[int]:
    """The seeds whose records are committed under ``scores_dir`` (each record's ``result.json``
    names its seed)."""
    import json

    return {int(json.loads(p.read_text())["seed"]) for p in scores_dir.glob("*/result.json")}


def seeds_to_run(cfg: Mapping[str, Any], scores_dir: Path) -> list[int] | None:
    """The sweep's seeds still to run: ``cfg.seeds`` less the committed ones ([] = nothing to run);
    None where the config names no seeds (one run per job at the run config's seed, which stands
    once any record is committed)."""
    if cfg.get("seeds") is None:
        return [] if any(scores_dir.glob("*/result.json")) else None
    return sorted(set(int(s) for s in cfg["seeds"]) - committed_seeds(scores_dir))


def sweep_table_steps(cfg: Mapping[str, Any], *, root: Path) -> list[Step]:
    """Data, the sweep, the committed scores and the table of Table 1 or 3 at ``cfg``'s scale.

    With ``cfg.seeds`` the sweep runs each job at the seeds whose records are not committed yet
    (``seed=1,2``: Hydra names the job folders by it), so adding a seed to a committed table runs
    that seed only; its steps' markers name the seeds, the commit copies the new jobs beside the
    committed ones."""
    work = (root / cfg["work"]).resolve()
    data, runs = work / "data", work / "runs"
    scores_dir, tables_dir = root / cfg["scores_dir"], root / cfg["tables_dir"]
    name = f"table{cfg['table']}"
    done = work / ".done"
    seeds = seeds_to_run(cfg, scores_dir)
    seed_args = [f"seed={','.join(map(str, seeds))}"] if seeds else []
    tag = f"_s{'_'.join(map(str, seeds))}" if seeds else ""
    label = f" (seeds {', '.join(map(str, seeds))})" if seeds else ""
    scale = cfg["scale"]
    n_scenes = preset_scene_count(root / "conf", cfg["preset"], cfg["data_overrides"])
    steps = [
        Step("data", done / "data", [tool("gspi-data"), f"preset={cfg['preset']}", f"out={data}", "seed=0",
                                     *cfg["data_overrides"]],
             cpu_s_left=lambda: None if n_scenes is None else cost(scale, "data: benchmark", n_scenes)),
        Step(f"{name}: sweep{label}", done / f"sweep{tag}",
             [tool("gspi-run"), "-m", f"data={data}", f"out={runs}", f"+experiment={cfg['experiment']}",
              *cfg["run_overrides"], *seed_args], cpu_s_left=lambda: sweep_cost(cfg, root, seeds)),
        Step(f"{name}: commit scores{label}", done / f"scores{tag}",
             action=lambda: commit_sweep_records(runs, scores_dir, {"<work>": work, "<repo>": root}, seeds),
             cpu_s_left=lambda: cost(scale, "commit")),
    ]
    if seeds == []:
        steps = []  # committed scores stand (written all at once after the sweep): nothing to recompute
    table = Step("table", tables_dir / ".built", [tool("gspi-table"), str(scores_dir), f"out={tables_dir}",
                                                  f"table={name}"], rebuild=True,
                 cpu_s_left=lambda: cost(scale, "table"))
    for step in steps:
        step.aliases = {str(work): "<work>"}
    return steps + [table]


def sweep_cost(cfg: Mapping[str, Any], root: Path, seeds: list[int] | None) -> float | None:
    """CPU-seconds of the sweep: a seed's jobs as long as the committed records of ``cfg.timings``
    took on average per seed (their ``seconds``; each job one thread), times the seeds to run; without
    records, the scale's rate (gspi/reproduce/costs.py)."""
    recorded = recorded_job_seconds(root / cfg["timings"]) if cfg.get("timings") else {}
    if recorded:
        per_seed = sum(recorded.values()) / len(recorded)
        return per_seed * (len(seeds) if seeds else 1)
    return cost(cfg["scale"], f"sweep: table{cfg['table']}")
