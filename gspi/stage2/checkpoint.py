"""Stage II checkpoints: the training state file and the EMA-only file that ships.

Both are ``torch.save`` dicts of tensors and plain Python values (loadable with
``weights_only=True``):

    format "gspi-stage2", version 1, step, rcw_config (RCWConfig fields), config (the resolved
    ``stage2`` config + seed + data), ema (EMA state_dict), and for training checkpoints also
    model, optimizer, rng (numpy data / torch loss / torch global states), elapsed_s.

:func:`load_stage2_checkpoint` rebuilds the denoiser with the EMA weights from either kind.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch

from eval.common.atomic import atomic_path
from eval.common.errors import MissingInputError, StatedError
from gspi.stage2.model import RCWConfig, RCWDenoiser

CHECKPOINT_FORMAT = "gspi-stage2"
CHECKPOINT_VERSION = 1


class CheckpointError(StatedError, ValueError):
    """A Stage II checkpoint is missing, unreadable or incompatible (the message names the file)."""


def rcw_config_dict(config: RCWConfig) -> dict:
    return dataclasses.asdict(config)


def save_atomic(obj: dict, path: str | Path) -> Path:
    """``torch.save`` to a temporary file, then rename (a crash never leaves half a checkpoint)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)
    return path


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Loads and validates the header of a Stage II checkpoint.

    Raises:
        MissingInputError: no file at ``path`` (a ``FileNotFoundError``).
        CheckpointError: unreadable, not a Stage II checkpoint, or an unsupported version.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingInputError(f"{path}: Stage II checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle/zip errors of a truncated or foreign file
        raise CheckpointError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a Stage II checkpoint (format != {CHECKPOINT_FORMAT!r})")
    if ckpt.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path}: checkpoint version {ckpt.get('version')!r} is not supported "
                              f"(expected {CHECKPOINT_VERSION})")
    for key in ("rcw_config", "config", "ema", "step"):
        if key not in ckpt:
            raise CheckpointError(f"{path}: checkpoint lacks {key!r}")
    return ckpt


def rcw_config_from(ckpt: dict, path: str | Path) -> RCWConfig:
    try:
        return RCWConfig(**ckpt["rcw_config"])
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: incompatible model config ({exc})") from exc


def load_weights(model: torch.nn.Module, state: dict, path: str | Path, what: str) -> None:
    """``load_state_dict(strict=True)`` (casting fp16 weights up) with errors naming the file."""
    ref = model.state_dict()
    try:
        state = {k: v.to(ref[k].dtype) if k in ref else v for k, v in state.items()}
        model.load_state_dict(state, strict=True)
    except (RuntimeError, KeyError) as exc:
        raise CheckpointError(f"{path}: {what} weights do not fit the model ({exc})") from exc


def load_stage2_checkpoint(path: str | Path) -> tuple[RCWDenoiser, dict]:
    """The Stage II denoiser with its EMA weights, in eval mode, and the config it was trained with.

    Args:
        path: a training checkpoint (``<out>/checkpoint.pt``) or a shipped EMA-only file.
    Returns:
        (model, cfg): cfg = {"stage2": ..., "seed": ..., ...} as saved, ``stage2`` the checked
        ``Stage2Config`` (keys added since the file was written take their defaults).
    Raises:
        FileNotFoundError / CheckpointError naming ``path``.
    """
    from gspi.stage2.config import complete_stage2

    ckpt = read_checkpoint(path)
    model = RCWDenoiser(rcw_config_from(ckpt, path))
    load_weights(model, ckpt["ema"], path, "EMA")
    cfg = dict(ckpt["config"])
    try:  # an older checkpoint's config lacks newer keys: their defaults (gspi.stage2.config)
        cfg["stage2"] = complete_stage2(cfg["stage2"])
    except (KeyError, ValueError) as exc:
        raise CheckpointError(f"{path}: its stored Stage II config is not valid: {exc}") from None
    return model.eval().requires_grad_(False), cfg


def portable_config(config: dict) -> dict:
    """A checkpoint's stored config with every absolute path made portable: under the repository
    by its relative path, elsewhere as ``<elsewhere>/<last two parts>`` (a shipped file names no
    machine's folders, issue 53; the paths are a record only, nothing reads them back)."""
    from eval.portable import portable

    from gspi.repo import REPO

    return portable(config, {"": REPO})


def ema_only(ckpt: dict, *, half: bool = False) -> dict:
    """The shippable EMA-only content of a training checkpoint (optionally fp16 weights), its
    config's paths made portable."""
    ema = {k: (v.half() if half and v.is_floating_point() else v) for k, v in ckpt["ema"].items()}
    keep = {k: ckpt[k] for k in ("format", "version", "step", "rcw_config", "config", "elapsed_s") if k in ckpt}
    keep["config"] = portable_config(keep["config"])
    return {**keep, "ema": ema, "weights": "ema" + ("-fp16" if half else "")}


def export_ema_only(src: str | Path, dst: str | Path, *, half: bool = False) -> Path:
    """Writes the shippable EMA-only file of a training checkpoint (optionally fp16 weights)."""
    return save_atomic(ema_only(read_checkpoint(src), half=half), dst)


def make_portable(path: str | Path) -> bool:
    """Rewrites a Stage II checkpoint in place with :func:`portable_config` (weights and every
    other entry unchanged); False when its config named no absolute path (file untouched)."""
    ckpt = read_checkpoint(path)
    config = portable_config(ckpt["config"])
    if config == ckpt["config"]:
        return False
    save_atomic({**ckpt, "config": config}, path)
    return True
