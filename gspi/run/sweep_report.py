"""What a `gspi-run -m` sweep did, told on its last line (a Hydra callback, conf/gspi_run.yaml).

Each job runs to its end whatever happens to the others (a failed job records its error in its
``result.json``); the sweep then ends with one line: ``sweep complete: N jobs (k skipped as
already complete)`` and exit 0, or ``<k> of <N> jobs failed: <job> (<error>); ...`` on stderr and
exit 1. A job's own last log line names the job (its ``override_dirname``) and its status.

Jobs may run in other processes (``hydra/launcher=joblib``, submitit), so each job leaves its
outcome in ``<sweep>/.sweep_jobs/<job number>.json``: ``started`` when it begins, its status when
it ends. The sweep's start removes the previous sweep's files (by name); its end reads them, so a
job whose process died (killed for memory) is reported as ended without an outcome.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Optional

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from eval.common.atomic import write_json_atomic
from eval.common.errors import one_line

FOLDER = ".sweep_jobs"
EXIT_JOBS_FAILED = 1
SHOWN_ERROR = 160  # characters of each failed job's error on the last line


def job_name(hydra: DictConfig) -> str:
    """The job's name as its folder shows it (``ablation=a2_no_view_onehot,seed=1``), from the
    job's ``hydra`` node (``HydraConfig.get()``, or a callback's ``config.hydra``)."""
    return str(hydra.job.get("override_dirname") or "") or Path(hydra.runtime.output_dir).name


def outcome_of(result: Any) -> tuple[str, Optional[str]]:
    """(status, error) of what a job's task returned (``gspi.cli.run.run_task``)."""
    if isinstance(result, dict):
        return str(result.get("status") or "failed"), result.get("error")
    if isinstance(result, BaseException):
        return "failed", f"{type(result).__name__}: {one_line(result)}"
    return "failed", "the job returned no result"


class SweepReport(Callback):
    """Hydra callback: records each job's outcome, prints the sweep's last line, sets its exit status."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        folder = Path(config.hydra.sweep.dir) / FOLDER
        for old in folder.glob("*.json") if folder.is_dir() else []:
            old.unlink()

    def _write(self, config: DictConfig, entry: dict) -> None:
        if str(config.hydra.mode) != "RunMode.MULTIRUN":
            return
        write_json_atomic(Path(config.hydra.sweep.dir) / FOLDER / f"{int(config.hydra.job.num)}.json",
                          {"job": job_name(config.hydra), "dir": str(config.hydra.runtime.output_dir), **entry})

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._write(config, {"status": "started", "error": None})

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        result = job_return._return_value  # the task's return, or the exception it raised
        status, error = outcome_of(result)
        skipped = isinstance(result, dict) and bool(result.get("skipped"))
        self._write(config, {"status": status, "error": error, "skipped": skipped})

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        line, failed = sweep_summary(Path(config.hydra.sweep.dir))
        if failed:
            print(f"{Path(sys.argv[0]).name}: error: {line}", file=sys.stderr)
            sys.exit(EXIT_JOBS_FAILED)  # SystemExit passes Hydra's callback guard (it catches Exception)
        print(line)


def read_outcomes(sweep_dir: Path) -> list[dict]:
    """The jobs of the last sweep into ``sweep_dir``, in job order."""
    folder = Path(sweep_dir) / FOLDER
    files = sorted(folder.glob("*.json"), key=lambda p: int(p.stem) if p.stem.isdigit() else -1)
    out = []
    for path in files:
        try:
            out.append(json.loads(path.read_text()))
        except (OSError, ValueError):
            out.append({"job": path.stem, "status": "started", "error": None})
    return out


def sweep_summary(sweep_dir: Path) -> tuple[str, bool]:
    """(the sweep's last line, whether any job failed or ended without an outcome)."""
    jobs = read_outcomes(sweep_dir)
    bad = [j for j in jobs if j.get("status") != "complete"]
    if not bad:
        skipped = sum(bool(j.get("skipped")) for j in jobs)
        return (f"sweep complete: {len(jobs)} job(s) complete"
                f"{f' ({skipped} skipped as already complete)' if skipped else ''} in {sweep_dir}; "
                f"tables: gspi-table {sweep_dir}"), False

    def why(job: dict) -> str:
        if job.get("status") == "started":
            return "ended without an outcome (its process died)"
        error = one_line(str(job.get("error") or "no error recorded"))
        return error if len(error) <= SHOWN_ERROR else error[:SHOWN_ERROR - 3] + "..."

    named = "; ".join(f"{j.get('job')} ({why(j)})" for j in bad)
    return (f"sweep finished with {len(bad)} of {len(jobs)} job(s) failed: {named}; each job's error is "
            f"in its result.json under {sweep_dir}; rerun the same command to redo only the failed jobs"), True
