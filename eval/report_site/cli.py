"""gspi-report: run or sweep folders -> a static HTML report (open index.html from disk).

Examples:
    gspi-report demo_out/runs out=demo_out/report
    gspi-report multirun/2025-01-01/12-00-00 out=report max_views=4
    gspi-report runs/a runs/b out=report gt=data/small figures=false

Reads only what runs leave on disk (docs/TABLES.md, docs/FORMAT.md): result.json, the
gspi-eval folders, predictions/, the dataset's ground truth, .hydra/config.yaml, run.log and
relight/<scene>/turntable.webp (gspi-relight). No server, no network. docs/REPORT.md.
"""
from __future__ import annotations

from pathlib import Path

from eval.common.errors import MissingInputError


def report_progress(line: str) -> None:
    """A progress line of the build (one per step and scene page) on stderr."""
    import sys

    print(f"gspi-report: {line}", file=sys.stderr, flush=True)


def run(cfg):
    """Build the report of `cfg.runs` into `cfg.out`; returns the Site."""
    from omegaconf import OmegaConf

    from eval.report_site.build import build_report

    runs = list(cfg.runs) if cfg.runs else []
    if not runs:
        raise ValueError("give run or sweep folders: gspi-report DIR [DIR ...] out=<dir>")
    missing = [r for r in runs if not Path(r).exists()]
    if missing:
        raise MissingInputError(f"run folder(s) not found: {', '.join(missing)}")
    site = build_report(runs, cfg.out, data=cfg.gt, max_views=cfg.max_views,
                        thumb=int(cfg.thumb), quality=int(cfg.quality),
                        bootstrap=OmegaConf.to_container(cfg.bootstrap, resolve=True),
                        figures=bool(cfg.figures), progress=report_progress)
    no_gt = sorted(str(p.where) for p in site.problems if p.kind == "missing data")
    if no_gt and not site.scene_pages:  # a report of nothing is an error, not exit 0
        where = f"gt={cfg.gt}" if cfg.gt else "the runs' recorded dataset (result.json 'data')"
        raise MissingInputError(f"no ground truth for scene(s) {', '.join(no_gt)} in {where}: give gt=<the "
                                f"dataset folder> or gt=<the scene's own folder>; {site.index} lists the problems")
    print(f"report: {len(site.scene_pages)} scene page(s), {len(site.problems)} problem(s) "
          f"listed, {site.size_bytes / 1e6:.1f} MB")
    print(f"open {site.index.resolve().as_uri()}")
    return site


def main() -> None:
    from eval.common.cli_entry import hydra_cli
    from eval.tables.cli import positional_to_overrides

    hydra_cli(run, "gspi_report", rewrite=positional_to_overrides)()


if __name__ == "__main__":
    main()
