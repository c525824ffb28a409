"""gspi-run: a method on a dataset's test scenes -> predictions, evaluation, figures, result.json.

Examples:
    gspi-run data=data/small out=runs/gspi                                  # GS-PI, shipped Stage II
    gspi-run data=data/small out=runs/nd method=no_decomposition
    gspi-run data=data/small out=runs/x assets=runs/recon scenes=[s002_multipart_ceramic]
    gspi-run data=my_scene out=runs/mine assets=my_scene/point_cloud.ply   # a user's own 2DGS PLY
    gspi-run -m data=data/tiny out=runs/t3 +experiment=table3               # a sweep (Table 3)
    gspi-run -m data=data/small out=runs/t2 +experiment=table2 hydra/launcher=joblib

Rerunning a command skips complete jobs and redoes only the rest (gspi/run/runner.py). In a
multirun (-m) a failed job records its error in its result.json and the sweep goes on; a
single run exits non-zero. Config: conf/gspi_run.yaml; tables: gspi-table <out>.
"""
from __future__ import annotations

import logging

from omegaconf import DictConfig, OmegaConf

from eval.cli_entry import hydra_cli

log = logging.getLogger(__name__)
# Quoted for Hydra's grammar when they hold = , ' spaces or non-ASCII (eval/argv.py).
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


def run_task(cfg: DictConfig) -> None:
    """One gspi-run job (of a multirun: its own sub-folder of `out`)."""
    from gspi.run.assets import check_user_assets
    from gspi.run.runner import run_job

    check_user_assets(cfg.get("assets"))  # a bad asset file: one line before the job starts
    job_cfg = resolved_config(cfg)
    if is_multirun():  # each job writes into its own sub-folder of the sweep folder `out`
        from hydra.core.hydra_config import HydraConfig

        job_cfg["out"] = HydraConfig.get().runtime.output_dir
    result = run_job(job_cfg, reraise=not is_multirun())
    log.info("%s: %s", cfg.out, result.get("status") if result else "no result")


def main() -> None:
    from eval.config import register_configs

    register_configs()
    hydra_cli(run_task, "gspi_run", path_keys=PATH_KEYS)()


if __name__ == "__main__":
    main()
