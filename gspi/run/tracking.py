"""Experiment tracking: wandb (offline by default) or nothing, behind one small interface.

``logger=wandb`` (conf/logger/wandb.yaml) runs ``wandb.init(mode="offline", dir=<out>)``: no
network is needed and ``wandb sync <out>/wandb/offline-run-*`` uploads later. Runs of one
sweep share ``group`` (the sweep folder's name); ``job_type`` is the method. Logged: the
resolved config, per-stage seconds and peak memory per scene, Stage III losses, the metric
summary, the per-view table and the per-scene figures. ``logger=none`` never imports wandb.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Mapping, Optional

log = logging.getLogger(__name__)


class NullTracker:
    """``logger=none``: every call is a no-op."""

    run_dir: Optional[Path] = None

    def log(self, values: Mapping[str, Any], step: Optional[int] = None) -> None:
        return None

    def log_table(self, key: str, frame) -> None:
        return None

    def log_image(self, key: str, path: Path) -> None:
        return None

    def summary(self, values: Mapping[str, Any]) -> None:
        return None

    def finish(self, exit_code: int = 0) -> None:
        return None


class WandbTracker(NullTracker):
    """A wandb run (offline unless ``mode`` says otherwise)."""

    def __init__(self, cfg: Mapping[str, Any], run_cfg: Mapping[str, Any], out: Path):
        import wandb

        self._wandb = wandb
        out.mkdir(parents=True, exist_ok=True)
        self.run = wandb.init(project=cfg.get("project", "gspi"), entity=cfg.get("entity"),
                              mode=cfg.get("mode", "offline"), dir=str(out), group=cfg.get("group"),
                              job_type=str(run_cfg.get("method", {}).get("name", "run")),
                              name=cfg.get("run_name"), tags=list(cfg.get("tags") or []),
                              config=dict(run_cfg))  # finish() ends each run: no reinit needed
        self.run_dir = Path(self.run.dir).parent

    def log(self, values: Mapping[str, Any], step: Optional[int] = None) -> None:
        self.run.log(dict(values), step=step)

    def log_table(self, key: str, frame) -> None:
        self.run.log({key: self._wandb.Table(dataframe=frame)})

    def log_image(self, key: str, path: Path) -> None:
        self.run.log({key: self._wandb.Image(str(path))})

    def summary(self, values: Mapping[str, Any]) -> None:
        for k, v in values.items():
            self.run.summary[k] = v

    def finish(self, exit_code: int = 0) -> None:
        self.run.finish(exit_code=exit_code)
        # run.finish() returns before wandb-core has closed the run's .wandb log; teardown() waits
        # for the service to flush and exit. Its atexit hook would do the same, but it is not
        # reliable under joblib/multiprocessing workers, and in-process callers (tests, notebooks)
        # read the log right after run_job returns. The next wandb.init starts a fresh service.
        self._wandb.teardown(exit_code=exit_code)


def make_tracker(logger_cfg: Optional[Mapping[str, Any]], run_cfg: Mapping[str, Any], out: Path) -> NullTracker:
    """The tracker ``logger.name`` asks for (``none`` or ``wandb``)."""
    name = (logger_cfg or {}).get("name", "none")
    if name == "none":
        return NullTracker()
    if name == "wandb":
        return WandbTracker(logger_cfg, run_cfg, out)
    raise ValueError(f"logger.name must be 'none' or 'wandb', got {name!r}")


def flatten(prefix: str, values: Mapping[str, Any]) -> dict[str, float]:
    """{"a": {"b": 1}} -> {"prefix/a/b": 1} keeping numbers only."""
    out: dict[str, float] = {}
    for k, v in values.items():
        key = f"{prefix}/{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            out.update(flatten(key, v))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[key] = float(v)
    return out
