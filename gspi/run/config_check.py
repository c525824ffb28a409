"""Start-up check of a `gspi-run` job config: every value the job will use, before it writes.

The stage configs are built (and so checked: names, types, ranges) once, here, and handed down
as the checked objects (:class:`StageConfigs`: the run's methods take them, nothing parses a
stage node again); the protocol by ``eval.config.validate_protocol``, the job's own keys here. A
bad value fails the job at start-up with ``<key>=<value>: must be ...``, never half-way through
a scene.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Optional

from gspi.strict_config import ConfigError, check_value

# key -> (type, lo, hi); inclusive, None = open
JOB_KEYS = {"seed": (int, 0, None), "threads": (int, 1, 1024), "scene_workers": (int, 1, 1024)}


@dataclass(frozen=True)
class StageConfigs:
    """The run's stage configs, checked: ``ReconConfig``, ``Stage1Config``, ``Stage2Config``,
    ``Stage3Config`` (None where the run config has no such node)."""

    recon: Optional[Any] = None
    stage1: Optional[Any] = None
    stage2: Optional[Any] = None
    stage3: Optional[Any] = None


def parse_stage_configs(cfg: Mapping[str, Any]) -> StageConfigs:
    """Each stage node of ``cfg`` built by its config class (a bad value: a ConfigError naming it)."""
    from gspi.recon.trainer import ReconConfig
    from gspi.stage1.config import Stage1Config
    from gspi.stage2.config import Stage2Config
    from gspi.stage3.config import Stage3Config

    kinds = {"recon": ReconConfig, "stage1": Stage1Config, "stage2": Stage2Config, "stage3": Stage3Config}
    return StageConfigs(**{key: kind.from_dict(dict(cfg[key])) for key, kind in kinds.items()
                           if cfg.get(key) is not None})


def check_run_config(cfg: Mapping[str, Any]) -> StageConfigs:
    """The run's checked stage configs; raises a stated error (:class:`ConfigError`,
    ``ProtocolError``, ``MissingInputError``) naming the first key whose value is not allowed or
    whose file is missing."""
    from omegaconf import OmegaConf

    from eval.config import validate_protocol
    from eval.common.layout import SPLITS
    from gspi.device import resolve_device

    for key, (kind, lo, hi) in JOB_KEYS.items():
        if key in cfg:
            check_value(key, cfg[key], kind, lo=lo, hi=hi)
    check_value("split", cfg.get("split"), str, choices=SPLITS)
    resolve_device(cfg.get("device", "cpu"))  # device=cuda without CUDA fails here, naming the key
    for key in ("data_dir", "out"):
        check_value(key, cfg.get(key), str)
    from gspi.run.assets import AssetCheckConfig

    AssetCheckConfig.from_dict(cfg.get("asset_check"))
    if cfg.get("scenes") is not None:
        if not isinstance(cfg["scenes"], (list, tuple)):
            raise ConfigError(f"scenes={cfg['scenes']!r}: must be a list of scene names or null")
        from eval.common.layout import check_name
        for name in cfg["scenes"]:
            check_name(name, "scenes")
    stages = parse_stage_configs(cfg)
    if cfg.get("stage2") is not None:
        check_no_time_budget(cfg["stage2"])
        check_checkpoint_exists(cfg["stage2"])
    if cfg.get("eval") is not None:
        validate_protocol(OmegaConf.create(dict(cfg["eval"])))
    return stages


def check_checkpoint_exists(stage2: Mapping[str, Any]) -> None:
    """``stage2.checkpoint=<path>`` names a file (resolved as the run resolves it): a missing one
    fails at start-up, naming the key."""
    from eval.common.errors import MissingInputError
    from gspi.run.stage2_model import resolve_path

    path = stage2.get("checkpoint")
    if path and not resolve_path(str(path)).is_file():
        raise MissingInputError(f"stage2.checkpoint={path}: Stage II checkpoint not found")


TIME_BUDGETS = ("stop_after_minutes", "stop_after_cpu_minutes")


def check_no_time_budget(stage2: Mapping[str, Any]) -> None:
    """A Stage II model that gspi-run trains is cached by its config's hash and reused by every
    job of that config, so it must be the same model whatever the machine: a time budget
    (gspi-train's stop_after_*minutes) would make it depend on the machine's speed, and a
    budget-stopped run would never count as finished. Set the steps instead, or train with
    gspi-train and pass stage2.checkpoint=<path>."""
    if stage2.get("checkpoint"):
        return
    train = stage2.get("train") or {}
    for key in TIME_BUDGETS:
        if train.get(key) is not None:
            raise ConfigError(f"stage2.train.{key}={train[key]}: gspi-run trains Stage II to "
                             f"stage2.train.steps (its model is cached by config and must not depend "
                             f"on the machine's speed); set stage2.train.{key}=null and the steps, or "
                             f"train with gspi-train and pass stage2.checkpoint=<its checkpoint.pt>")
