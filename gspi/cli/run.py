"""gspi-run: a method on a dataset's test scenes -> predictions, evaluation, figures, result.json.

Examples:
    gspi-run data=data/small out=runs/gspi                                  # GS-PI, shipped Stage II
    gspi-run data=data/small out=runs/nd method=no_decomposition
    gspi-run data=data/small out=runs/x assets=runs/recon scenes=[s002_multipart_ceramic]
    gspi-run data=my_scene out=runs/mine assets=my_scene/point_cloud.ply   # a user's own 2DGS PLY
    gspi-run -m data=data/tiny out=runs/t3 +experiment=table3               # a sweep (Table 3)
    gspi-run -m data=data/small out=runs/t2 +experiment=table2 hydra/launcher=joblib

Rerunning a command skips complete jobs and redoes only the rest (gspi/run/runner.py). In a
multirun (-m) a failed job records its error in its result.json and the sweep goes on; the
sweep's last line is "sweep complete: N job(s) ..." (exit 0) or names the failed jobs (exit 1,
gspi/run/sweep_report.py); a sweep whose Stage II checkpoint cannot serve a job is refused
before any job starts (gspi/run/sweep_check.py). A single run exits non-zero. Config: conf/gspi_run.yaml; tables: gspi-table <out>.
"""
from __future__ import annotations

import logging
import traceback
from pathlib import Path
from typing import Optional

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli

log = logging.getLogger(__name__)
# Quoted for Hydra's grammar when they hold = , ' spaces or non-ASCII (eval/common/argv.py).
PATH_KEYS = ("data_dir", "out", "assets", "cache_dir")


def resolved_config(cfg: DictConfig) -> dict:
    """Plain dict of the job's config without the `hydra` node."""
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("hydra", None)
    return plain


def is_multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    try:
        return HydraConfig.get().mode == RunMode.MULTIRUN
    except ValueError:
        return False


def run_task(cfg: DictConfig) -> Optional[dict]:
    """One gspi-run job (of a multirun: its own sub-folder of `out`). In a multirun the job
    never raises: its outcome (the record, or the error) is returned for the sweep's last line
    (gspi/run/sweep_report.py), and a job's log line names the job."""
    from gspi.run.assets import check_user_assets
    from gspi.run.runner import run_job

    if not is_multirun():
        check_user_assets(cfg.get("assets"))  # a bad asset file: one line before the job starts
        result = run_job(resolved_config(cfg), reraise=True)
        log.info("%s: %s", cfg.out, result.get("status") if result else "no result")
        return result
    from hydra.core.hydra_config import HydraConfig

    from eval.common.errors import StatedError, one_line
    from gspi.run.record import RESULT_FILE
    from gspi.run.sweep_report import job_name

    name = job_name(HydraConfig.get())
    out = Path(HydraConfig.get().runtime.output_dir)  # each job writes into its own sub-folder
    before = _mtime(out / RESULT_FILE)
    try:
        check_user_assets(cfg.get("assets"))
        job_cfg = resolved_config(cfg)
        job_cfg["out"] = str(out)
        result = dict(run_job(job_cfg, reraise=False) or {"status": "failed", "error": "no result.json written"})
    except Exception as exc:  # recorded for the sweep's last line; the other jobs go on (Ctrl-C stops all)
        if not isinstance(exc, StatedError):
            log.error("job %s: failed:\n%s", name, traceback.format_exc())
        result = {"status": "failed", "error": f"{type(exc).__name__}: {one_line(exc)}"}
    result["skipped"] = before is not None and before == _mtime(out / RESULT_FILE)
    if result.get("status") == "complete":
        log.info("job %s: complete%s", name, " (skipped: a complete result was found)" if result["skipped"] else "")
    else:
        log.error("job %s: failed: %s", name, one_line(str(result.get("error"))))
    return result


def _mtime(path: Path) -> Optional[int]:
    return path.stat().st_mtime_ns if path.is_file() else None


def main() -> None:
    from eval.config import register_configs

    register_configs()
    from gspi.run.sweep_check import check_gspi_run

    hydra_cli(run_task, "gspi_run", path_keys=PATH_KEYS, check=check_gspi_run)()


if __name__ == "__main__":
    main()
