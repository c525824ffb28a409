"""Before a `gspi-run` sweep starts: its dataset exists, and every job's Stage II checkpoint must
serve the job's config.

``gspi-run -m ablation=full,a2_no_view_onehot`` with the shipped ``stage2.checkpoint`` ran the
Full job to the end and then failed A2 inside its job (a ``ConfigError`` from
``gspi.run.stage2_model.check_compatible``: the checkpoint was trained with another local
condition). Here the jobs' Stage II configs are composed from the command line (each value of
the sweeps over ``ablation``, ``stage2`` and ``stage2.*``, on the command line or in an
experiment's ``hydra.sweeper.params``) and checked against the checkpoint's stored config with
that same function before any job starts, so the refusal is one line naming the key to set.
"""
from __future__ import annotations

import itertools
from pathlib import Path
from typing import Optional

from gspi.strict_config import ConfigError

MULTIRUN_FLAGS = ("-m", "--multirun")
MAX_JOBS_CHECKED = 64  # compositions (about 0.3 s each); a larger sweep checks its first 64


def is_stage2_key(key: str) -> bool:
    return key in ("ablation", "stage2") or key.startswith("stage2.")


def check_sweep_data(cfg, swept: set[str]) -> None:
    """The dataset (and its scenes) every job reads, when no sweep varies it: a missing one is one
    line before the sweep, not the same failure in every job (the runner's own ``select_scenes``)."""
    from gspi.run.runner import select_scenes

    if swept & {"data_dir", "split", "scenes"}:
        return
    scenes = list(cfg.scenes) if cfg.get("scenes") is not None else None
    select_scenes(Path(str(cfg.data_dir)), str(cfg.split), scenes)


def stage2_sweeps(config_dir: str, config_name: str, overrides: list[str]) -> dict[str, list[str]]:
    """{key: values} of the sweeps that can change a job's Stage II config: the command line's,
    then an experiment's ``hydra.sweeper.params`` (which the command line's override). Checks the
    dataset first (:func:`check_sweep_data`)."""
    from hydra import compose, initialize_config_dir

    from eval.common.cli_precheck import first_of_sweeps, sweep_values

    swept = sweep_values(overrides)
    found = {k: v for k, v in swept.items() if is_stage2_key(k)}
    with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
        cfg = compose(config_name=config_name, overrides=first_of_sweeps(overrides), return_hydra_config=True)
    params = cfg.hydra.sweeper.get("params") or {}
    check_sweep_data(cfg, set(swept) | {str(k) for k in params})
    for key, value in params.items():
        if is_stage2_key(str(key)) and str(key) not in found:
            found.update(sweep_values([f"{key}={value}"]) or {str(key): [str(value)]})
    return found


def checkpoint_problem(stage2_node, cache: dict) -> Optional[str]:
    """Why a job whose ``stage2`` node is ``stage2_node`` would fail at Stage II: a bad value, or
    a ``stage2.checkpoint`` that cannot serve it (the job's own check, ``check_compatible``); or None."""
    from gspi.run.stage2_model import check_compatible, resolve_path
    from gspi.stage2.checkpoint import read_checkpoint
    from gspi.stage2.config import complete_stage2

    try:
        job = complete_stage2(dict(stage2_node))  # the job's own start-up check of its stage2 node
    except ValueError as exc:  # ConfigError, or a combination the config refuses (A1 + pixel features)
        return str(exc)
    ckpt = stage2_node.get("checkpoint")
    if not ckpt:
        return None
    path = resolve_path(str(ckpt))
    if not path.is_file():
        return None  # the job's start-up check names the missing file (check_checkpoint_exists)
    if path not in cache:
        cache[path] = complete_stage2(dict(read_checkpoint(path)["config"])["stage2"])
    try:
        check_compatible(cache[path], job, path)
    except ConfigError as exc:
        return str(exc)
    return None


def check_sweep_checkpoints(argv: list[str], config_dir: str, config_name: str = "gspi_run") -> None:
    """Raises :class:`ConfigError` naming the first job (its sweep values) whose Stage II
    checkpoint does not match its config, and the key to set."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from eval.common.cli_precheck import first_of_sweeps

    overrides = [a for a in argv if a not in MULTIRUN_FLAGS]
    if any(a.startswith("-") for a in overrides):
        return  # Hydra's own modes (--cfg, --help, ...)
    sweeps = stage2_sweeps(config_dir, config_name, overrides)
    if not sweeps:
        return
    base = [o for o in first_of_sweeps(overrides) if o.lstrip("+~").split("=", 1)[0] not in sweeps]
    cache: dict = {}
    combos = itertools.islice(itertools.product(*sweeps.values()), MAX_JOBS_CHECKED)
    with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
        for values in combos:
            job = [f"{k}={v}" for k, v in zip(sweeps, values)]
            cfg = compose(config_name=config_name, overrides=base + job)
            stage2 = OmegaConf.to_container(cfg.stage2, resolve=True)
            problem = checkpoint_problem(stage2, cache)
            if problem:
                raise ConfigError(f"sweep job {','.join(job)}: {problem} (refused before any job started)")


def check_gspi_run(argv: list[str]) -> None:
    """`gspi-run`'s check before Hydra starts (eval.common.cli_entry.hydra_cli's ``check``): sweeps only."""
    from eval.common.conf import CONF_DIR

    if any(a in MULTIRUN_FLAGS for a in argv) or any("experiment=" in a for a in argv):
        check_sweep_checkpoints(argv, str(Path(CONF_DIR)))
