"""`build_report`: run/sweep folders -> the static site: index.html here, scene pages in
scene_page.py, figures in figures.py."""
from __future__ import annotations

import datetime
import shutil
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import Callable

from eval.common.imageio import read_exr
from eval.common.layout import LayoutError, read_scene, scene_dir_in
from eval.report_site.collect import Job, Problem, collect_jobs, read_per_view
from eval.report_site.html_tables import frame_html, sweep_table_html
from eval.report_site.images import envmap_preview
from eval.report_site.page import page, url
from eval.report_site.panels import relight_config, scene_panels
from eval.report_site.scene_page import SceneWriter
from eval.scored_view import EnvironmentCache

MAX_COPY_BYTES = 2_000_000   # a log longer than this is copied as its last 2 MB


@dataclass
class Site:
    """What was written; returned to the CLI and the tests."""

    out: Path
    index: Path
    scene_pages: dict[str, Path] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)
    tables: dict = field(default_factory=dict)

    @property
    def size_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.out.rglob("*") if p.is_file())


def build_tables(paths: list, bootstrap: dict, problems: list[Problem]):
    """(Sweep, {name: SweepTable}); a sweep that cannot be tabulated becomes a problem."""
    from eval.sweep import SweepError, load_sweep
    from eval.tables.build import TABLE_SPECS, build_sweep_table

    try:
        sweep = load_sweep(paths)
        built = {n: build_sweep_table(sweep, spec, bootstrap=bootstrap)
                 for n, spec in TABLE_SPECS.items()}
    except (SweepError, ValueError) as exc:
        problems.append(Problem(Path(str(paths[0])), "tables", f"tables not built: {exc}"))
        return None, {}
    return sweep, {n: t for n, t in built.items() if t is not None}


def shown_jobs(jobs: list[Job]) -> list[Job]:
    """Jobs whose images the scene pages show: one per row label (the first seed), Table 1
    rows and any other job with predictions."""
    seen, out = set(), []
    for job in jobs:
        if job.label in seen or (job.table != "table1" and job.predictions is None):
            continue
        seen.add(job.label)
        out.append(job)
    return out


def scene_sources(jobs: list[Job]) -> dict[str, Path]:
    """scene name -> its ground-truth folder (from the first job whose dataset has it; the
    dataset may be the scene's own folder, as after ``gspi-run data=<scene folder>``)."""
    out = {}
    for job in jobs:
        for scene in job.scenes:
            found = scene_dir_in(job.data, scene) if job.data is not None else None
            if scene not in out and found is not None:
                out[scene] = found
    return out


def _copy_capped(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    data = src.read_bytes()
    if len(data) > MAX_COPY_BYTES:
        data = b"[... truncated: last 2 MB of " + str(src).encode() + b"]\n" + data[-MAX_COPY_BYTES:]
    dst.write_bytes(data)


def jobs_html(jobs: list[Job], out: Path) -> str:
    """The jobs table: row label, table, seed, run folder, links to copied config and log."""
    rows = []
    for k, job in enumerate(jobs):
        links = []
        for name, src in (("config", job.config), ("log", job.log)):
            if src is not None:
                rel = f"jobs/{k}/{src.name}"
                _copy_capped(src, out / rel)
                links.append(f"<a href=\"{url(rel)}\">{name}</a>")
        rows.append(f"<tr><td data-v=\"{escape(job.label)}\">{escape(job.label)}</td>"
                    f"<td data-v=\"{job.table}\">{job.table}</td><td data-v=\"{job.seed}\">"
                    f"{job.seed}</td><td data-v=\"{escape(str(job.run_dir))}\">"
                    f"{escape(str(job.run_dir))}</td><td>{' '.join(links) or '--'}</td></tr>")
    return ("<table class=\"metrics\" id=\"jobs\"><thead><tr><th>Row</th><th>Table</th><th>Seed"
            "</th><th>Run folder</th><th>Files</th></tr></thead><tbody>" + "".join(rows)
            + "</tbody></table>")


def problems_html(problems: list[Problem]) -> str:
    if not problems:
        return "<p>None: every job completed and every scene has predictions.</p>"
    items = "".join(f"<li><b>{escape(p.kind)}</b>: {escape(p.message)} "
                    f"<small>({escape(str(p.where))})</small></li>" for p in problems)
    return f"<ul class=\"problems\">{items}</ul>"


def write_scene(out: Path, scene_dir: Path, jobs: list[Job], all_jobs: list[Job], per_view: dict,
                *, max_views, thumb, quality, env_cache=None) -> tuple[Path, tuple]:
    """The scene's page; returns it and (the first view's panels, environments) for figures.
    ``env_cache``: an ``EnvironmentCache`` kept across the report's scenes."""
    scene = read_scene(scene_dir)
    panels, envs = scene_panels(scene, jobs, per_view, max_views=max_views, env_cache=env_cache)
    protocol = next((j.protocol for j in jobs if j.protocol), {})
    cfg = relight_config(protocol)
    env_images = {e: envmap_preview(read_exr(scene.envmap_path(e)), cfg) for e in envs}
    writer = SceneWriter(out, scene, jobs, thumb=thumb, quality=quality)
    return writer.write(panels, envs, env_images, all_jobs), (panels[0], envs)


SITE_DIRS = ("img", "anim", "jobs", "figures")


def clear_site(out: Path) -> None:
    """Remove what a previous report wrote in `out` (its folders and pages), nothing else:
    `out` may be a folder that holds other files (and Hydra's log of this run)."""
    out.mkdir(parents=True, exist_ok=True)
    for name in SITE_DIRS:
        if (out / name).is_dir():
            shutil.rmtree(out / name)
    for page_path in [out / "index.html", *out.glob("scene_*.html")]:
        page_path.unlink(missing_ok=True)


def build_report(paths: list[str | Path], out: str | Path, *, data: str | None = None,
                 max_views: int | None = None, thumb: int = 128, quality: int = 80,
                 bootstrap: dict | None = None, figures: bool = True,
                 progress: Callable[[str], None] | None = None) -> Site:
    """Write the site for the jobs below `paths` into `out` (a previous site there is replaced);
    returns what was written. ``progress(line)``, when given, gets one line per step (the tables,
    each scene page ``scene k/N: <name>``, the figures, the index)."""
    say = progress or (lambda line: None)
    out = Path(out)
    clear_site(out)
    jobs, problems = collect_jobs(paths, data=data)
    say(f"{len(jobs)} complete job(s) found; building the tables")
    sweep, tables = build_tables(list(paths), dict(bootstrap or {}), problems)
    shown = shown_jobs(jobs)
    per_view = {j.label: read_per_view(j) for j in shown}
    site = Site(out=out, index=out / "index.html", problems=problems, tables=tables)
    sources, first_views = scene_sources(jobs), {}
    scenes = sorted({s for j in jobs for s in j.scenes})
    env_cache = EnvironmentCache()  # one prefiltering per distinct map over all scenes
    for k, scene in enumerate(scenes, 1):
        say(f"scene {k}/{len(scenes)}: {scene}")
        lacking = [j.label for j in shown if j.prediction(scene) is None]
        problems += [Problem(j.run_dir, "missing prediction", f"{j.label} has no prediction "
                             f"for {scene}") for j in shown if j.label in lacking
                     and scene not in j.scene_errors]
        if scene not in sources:
            problems.append(Problem(Path(scene), "missing data", f"{scene}: no ground truth found"))
            continue
        try:
            site.scene_pages[scene], first_views[scene] = write_scene(out, sources[scene], shown, jobs, per_view,
                                                  max_views=max_views, thumb=thumb, quality=quality,
                                                  env_cache=env_cache)
        except (LayoutError, OSError, ValueError) as exc:
            problems.append(Problem(sources[scene], "scene page", f"{scene}: {exc}"))
    if figures and shown:
        from eval.report_site.figures import write_figures

        say("figures")
        try:
            site.figures = write_figures(out / "figures", shown, tables, first_views)
        except (LayoutError, OSError, ValueError) as exc:
            problems.append(Problem(out / "figures", "figures", f"figures not written: {exc}"))
    say(f"index: {site.index}")
    site.index.write_text(page("gspi report", index_body(site, jobs, sweep, paths, out)))
    return site


def index_body(site: Site, jobs: list[Job], sweep, paths, out: Path) -> str:
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    parts = [f"<h1>gspi report</h1><p>{len(jobs)} complete job(s) from "
             f"{escape(', '.join(map(str, paths)))}; written {when}. Click a column header to "
             "sort; best value of a column <span class=\"best\">red, bold</span>, second "
             "<span class=\"second\">yellow, underlined</span>.</p>",
             f"<h2>Failed and missing jobs</h2>{problems_html(site.problems)}", "<h2>Tables</h2>"]
    if not site.tables:
        parts.append("<p>No table: no complete run record.</p>")
    for name, table in site.tables.items():
        parts.append(sweep_table_html(table, sweep))
        parts.append(f"<h4>{escape(table.spec.title.split(':')[0])}: per scene, PSNR of the Δ "
                     f"column, mean over seeds</h4>"
                     + frame_html(table.per_scene, index_name="scene", table_id=f"{name}_per_scene"))
    links = "".join(f"<li><a href=\"{url(p.name)}\">{escape(s)}</a></li>"
                    for s, p in sorted(site.scene_pages.items()))
    parts.append(f"<h2>Scenes</h2><ul>{links or '<li>none</li>'}</ul>")
    if site.figures:
        figs = "".join(f"<figure class=\"tile\"><a href=\"figures/{p.name}\"><img src=\"figures/"
                       f"{p.name}\" style=\"width:auto;height:auto;max-width:520px;max-height:420px\" alt=\"{p.stem}\"></a>"
                       f"<figcaption>{p.stem} (<a href=\"figures/{p.stem}.pdf\">PDF</a>)"
                       f"</figcaption></figure>" for p in site.figures if p.suffix == ".png")
        parts.append(f"<h2>Figures</h2>{figs}")
    parts.append(f"<h2>Jobs</h2>{jobs_html(jobs, out)}")
    return "\n".join(parts)
