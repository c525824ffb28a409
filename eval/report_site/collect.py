"""Find what a report shows: the jobs of run/sweep folders, their files and what went wrong.

A job is one gspi-run folder (docs/TABLES.md): `result.json`, `predictions/<scene>/` (the
canonical layout), `eval/` (gspi-eval), `.hydra/config.yaml`, `run.log`, and optionally
`relight/<scene>/turntable.webp` (written by gspi-relight) and `export/<scene>/pbr_gs.glb` with
its still `pbr_gs_preview.png` beside it (written by `gspi-export asset=`; the preview's name is
gspi.export.asset.preview_path's, `<stem>_preview.png`, restated here: eval/ imports no gspi/). Nothing here raises on a bad job:
a malformed record, a failed or killed job becomes a `Problem` the page lists.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from eval.records.eval_folder import META_NAME
from eval.sweep import PREDICTION_DIRS, SweepError, find_records, read_record
from eval.tables.labels import row_label, row_order

LOG_NAMES = ("run.log",)
CONFIG_NAME = Path(".hydra") / "config.yaml"
ANIMATION = Path("relight") / "{scene}" / "turntable.webp"
GLB = Path("export") / "{scene}" / "pbr_gs.glb"
GLB_PREVIEW = Path("export") / "{scene}" / "pbr_gs_preview.png"


@dataclass
class Job:
    """One complete gspi-run job as the report sees it."""

    run_dir: Path
    method: str
    ablation: str
    table: str
    seed: int
    label: str                       # the paper's row name (eval.tables.labels)
    data: Path | None                # ground-truth dataset folder, None if not found
    predictions: Path | None
    eval_dir: Path | None
    scenes: tuple[str, ...]
    scene_errors: dict = field(default_factory=dict)   # scene -> error message (result.json)
    protocol: dict = field(default_factory=dict)       # eval_meta.json protocol_config

    @property
    def log(self) -> Path | None:
        found = [self.run_dir / n for n in LOG_NAMES if (self.run_dir / n).is_file()]
        return found[0] if found else None

    @property
    def config(self) -> Path | None:
        path = self.run_dir / CONFIG_NAME
        return path if path.is_file() else None

    def animation(self, scene: str) -> Path | None:
        path = self.run_dir / str(ANIMATION).format(scene=scene)
        return path if path.is_file() else None

    def glb(self, scene: str) -> tuple[Path, Path | None] | None:
        """(the scene's exported GLB, its preview image or None), None without a GLB."""
        path = self.run_dir / str(GLB).format(scene=scene)
        if not path.is_file():
            return None
        preview = self.run_dir / str(GLB_PREVIEW).format(scene=scene)
        return path, preview if preview.is_file() else None

    def prediction(self, scene: str) -> Path | None:
        """The method's folder for `scene`, None when it has none (a missing prediction)."""
        if self.predictions is None or not (self.predictions / scene).is_dir():
            return None
        return self.predictions / scene


@dataclass
class Problem:
    """A job or record the report cannot show, and why."""

    where: Path
    kind: str       # failed | killed | malformed | scene failed | missing data
    message: str


def resolve_data(name: str | None, run_dir: Path, override: str | None) -> Path | None:
    """The dataset folder of a record: `override`, else `name` if absolute, else `name`
    below the run folder or one of its ancestors (gspi-run stores the path it was given,
    usually relative to where it was started)."""
    candidates = [Path(override)] if override else []
    if name:
        p = Path(name)
        candidates += [p] if p.is_absolute() else [a / p for a in (run_dir, *run_dir.parents)]
        candidates.append(p)
    return next((c.resolve() for c in candidates if c.is_dir()), None)


def _protocol_config(eval_dir: Path | None) -> dict:
    if eval_dir is None or not (eval_dir / META_NAME).is_file():
        return {}
    try:
        meta = json.loads((eval_dir / META_NAME).read_text())
    except json.JSONDecodeError:
        return {}
    return meta.get("protocol_config") or {}


def _job(record, data_override: str | None) -> Job:
    raw = json.loads(record.path.read_text())
    predictions = next((record.run_dir / d for d in PREDICTION_DIRS
                        if (record.run_dir / d).is_dir()), None)
    return Job(run_dir=record.run_dir, method=record.method, ablation=record.ablation,
               table=record.table, seed=record.seed,
               label=row_label(record.method, record.ablation, record.table),
               data=resolve_data(record.data, record.run_dir, data_override),
               predictions=predictions, eval_dir=record.material_eval, scenes=record.scenes,
               scene_errors=dict(raw.get("scene_errors") or {}),
               protocol=_protocol_config(record.material_eval))


def collect_jobs(paths: list[str | Path], *, data: str | None = None
                 ) -> tuple[list[Job], list[Problem]]:
    """Complete jobs (paper row order, then seed) and every problem found below `paths`."""
    files, unfinished = find_records(paths)
    jobs, problems = [], []
    for path in files:
        try:
            record = read_record(path)
        except SweepError as exc:
            problems.append(Problem(path.parent, "malformed", str(exc)))
            continue
        if record.status == "failed":
            problems.append(Problem(record.run_dir, "failed",
                                    f"{record.method} [{record.ablation}] seed {record.seed}: "
                                    f"{record.error or 'no error message'}"))
            continue
        job = _job(record, data)
        if job.data is None:
            problems.append(Problem(job.run_dir, "missing data",
                                    f"dataset {record.data!r} not found (give gt=<dataset dir>)"))
        for scene, error in job.scene_errors.items():
            problems.append(Problem(job.run_dir, "scene failed", f"{job.label}, {scene}: {error}"))
        jobs.append(job)
    problems += [Problem(d, "killed", "job folder without result.json (killed or still "
                                      "running): nothing in it is shown") for d in unfinished]
    jobs.sort(key=lambda j: (row_order(j.method, j.ablation), j.table, j.seed, str(j.run_dir)))
    return jobs, problems


def read_per_view(job: Job) -> pd.DataFrame:
    """The job's per_view.csv (scene, view, channel, env, psnr, ssim, lpips); empty if none."""
    path = None if job.eval_dir is None else job.eval_dir / "per_view.csv"
    if path is None or not path.is_file():
        return pd.DataFrame(columns=["scene", "view", "channel", "env", "psnr", "ssim", "lpips"])
    frame = pd.read_csv(path, dtype={"view": str, "scene": str}, keep_default_na=False)
    return frame
