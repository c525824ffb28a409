"""`gspi-table`: evaluated runs -> the paper's Tables 1-3 (Markdown, LaTeX, CSV).

    gspi-table runs/gspi/eval runs/no_decomposition/eval out=tables
    gspi-table 'runs=[runs/a/eval,runs/b/eval]' out=tables
    gspi-table multirun/2025-01-01/12-00-00 out=tables             # a gspi-run sweep
    gspi-table multirun/... table=table2 bootstrap.n=20000 bootstrap.seed=1
    gspi-table multirun/... resources=true                         # + time and peak-memory columns

Three sources, one table builder and one renderer: folders holding gspi-run records
(result.json, docs/TABLES.md) give Tables 1-3 (`eval.sweep`); plain gspi-eval folders
(summary.json + eval_meta.json, searched recursively) give Table 1, each folder one run of its
method (`eval.records.eval_folder`); Stage II point-cloud evaluations (`python -m
gspi.stage2.evaluate_points`, scores.json) give Table 2, each folder one run of its
ablation (`eval.records.points_scores`). Either way every cell is mean ± SE over (scene, run) units, Δ
is the paired bootstrap against GS-PI where it is a row, and the footer names the protocol,
the image counts and every folder left out (`eval.tables.build`, `eval.tables.render`).
"--" marks a channel the method does not model; the best value of a column is bold (LaTeX:
red cell), the second underlined (LaTeX: yellow cell). Numbers are never typed by hand.
"""
from __future__ import annotations

from pathlib import Path


def is_sweep(paths: list[str | Path]) -> bool:
    """True when the folders hold gspi-run records, or Hydra job folders (even all killed) and
    no complete gspi-eval folder of their own: a killed gspi-eval folder next to complete ones
    does not turn them into a sweep (it is listed as incomplete in the table's footer), and
    the eval/ folder a killed gspi-run job left does not turn the job into a plain folder."""
    from eval.records.eval_folder import META_NAME, SUMMARY_NAME
    from eval.sweep import find_records

    records, unfinished = find_records(paths)
    if records:
        return True
    evals = [s.parent for p in paths if Path(p).exists() for s in Path(p).rglob(SUMMARY_NAME)
             if (s.parent / META_NAME).is_file()]
    return bool(unfinished) and not any(set(e.parents).isdisjoint(unfinished) for e in evals)


def load_sources(runs: list, tables: tuple[str, ...]):
    """The Sweep of gspi-run records below `runs`; else of their Stage II point-cloud
    evaluations (Table 2, `eval.records.points_scores`) when there are only those; else of their
    plain gspi-eval folders (Table 1)."""
    from eval.records.eval_folder import find_eval_folders
    from eval.records.points_scores import find_points_folders
    from eval.tables.sources import load_eval_folders, load_points_folders
    from eval.sweep import SweepError, load_sweep

    if is_sweep(runs):
        return load_sweep(runs, tables=tables)
    if find_points_folders(runs):
        try:
            find_eval_folders(runs)
        except FileNotFoundError:
            return load_points_folders(runs)
        raise SweepError(f"{', '.join(map(str, runs))}: holds both gspi-eval folders (Table 1) and "
                         "Stage II point-cloud evaluations (Table 2); tabulate them separately")
    return load_eval_folders(runs)


def run(cfg) -> dict:
    """Tables 1-3 (those with rows, or `cfg.table`) -> files; returns {name: SweepTable}."""
    from eval.sweep import TABLES, SweepError
    from eval.tables.render import to_markdown, write_sweep_table
    from eval.tables.build import TABLE_SPECS, build_sweep_table, with_resources

    runs = list(cfg.runs) if cfg.runs else []
    if not runs:
        raise SweepError("give evaluated run folders: gspi-table DIR [DIR ...] or runs=[...]")
    chosen = cfg.get("table")
    if chosen is not None and chosen not in TABLES:
        raise SweepError(f"table={chosen!r}: allowed values are {', '.join(TABLES)} or null")
    names = (chosen,) if chosen else TABLES
    sweep = load_sources(runs, names)
    boot = dict(cfg.get("bootstrap") or {})
    specs = {n: sweep.specs.get(n, TABLE_SPECS[n]) for n in names}
    if cfg.get("resources", False):
        specs = {n: with_resources(s) for n, s in specs.items()}
    built = {n: build_sweep_table(sweep, specs[n], bootstrap=boot) for n in names}
    built = {n: t for n, t in built.items() if t is not None}
    if not built:
        failed = "; ".join(f"{r.run_dir}: {r.error}" for r in sweep.failed)
        raise SweepError(f"no complete run record of {', '.join(names)} below "
                         f"{', '.join(map(str, cfg.runs))} ({len(sweep.failed)} failed"
                         f"{': ' + failed if failed else ''}; {len(sweep.unfinished)} job "
                         "folder(s) without result.json)")
    for table in built.values():
        write_sweep_table(table, sweep, Path(cfg.out))
        print(to_markdown(table, sweep))
    warn_rows_with_failed_jobs(sweep, names, built)
    return built


def warn_rows_with_failed_jobs(sweep, names, built: dict) -> None:
    """One stderr line per table whose rows lack jobs (failed, or killed before their record):
    the rows are named, so a table with fewer rows than the sweep ran is never silent."""
    import sys

    from eval.tables.build import rows_with_failed_jobs

    for name in names:
        table = built.get(name)
        short = rows_with_failed_jobs(sweep, name, table.rows if table is not None else ())
        if short:
            print(f"gspi-table: warning: {name}: rows with failed or unfinished jobs: {'; '.join(short)}",
                  file=sys.stderr)


def positional_to_overrides(argv: list[str]) -> list[str]:
    """Let `gspi-table DIR DIR` mean `gspi-table runs=[DIR,DIR]` (Hydra takes key=value only)."""
    # An existing path is a folder even with "=" in it (Hydra's sweep job folders: method=gspi).
    from eval.common.argv import needs_quoting, quote_path_overrides, quote_value

    dirs = [a for a in argv if not a.startswith("-") and ("=" not in a or Path(a).exists())]
    rest = quote_path_overrides([a for a in argv if a not in dirs], ("out",))
    quoted = ",".join(quote_value(d) if needs_quoting(d) else d for d in dirs)  # any folder name: = , ' spaces, non-ASCII
    return rest + ([f"runs=[{quoted}]"] if dirs else [])


def main() -> None:
    from eval.common.cli_entry import hydra_cli

    hydra_cli(run, "gspi_table", rewrite=positional_to_overrides)()


if __name__ == "__main__":
    main()
