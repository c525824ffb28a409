"""The Stage II model of a run: a given checkpoint, or one trained once per config and reused.

``stage2.checkpoint=<path>`` loads it (relative paths are tried against the working
directory, then the repository root, so the shipped ``checkpoints/stage2_pool224_pixel_5k.pt`` works
from anywhere). ``stage2.checkpoint=null`` trains ``gspi-train``'s recipe on the dataset's
training split into ``<cache>/stage2/<hash>/`` (hash of the Stage II config, the training
scenes' content and the seed: a moved or copied dataset reuses its model), resuming a partial run, under a file lock so that the parallel jobs of
a sweep that share a model (Table 3: A6-A9 and Full) train it once.
"""
from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

from eval.common.layout import read_splits
from gspi.pipeline import Stage2Context
from gspi.repo import REPO
from gspi.run.locks import file_lock
from gspi.run.record import config_hash
from gspi.run.scene_digest import scenes_digest
from gspi.strict_config import ConfigError

log = logging.getLogger(__name__)
# Keys of `stage2` that do not change the trained weights.
NOT_TRAINING = ("eval", "inference", "checkpoint", "validate")


def resolve_path(path: str | Path) -> Path:
    """``path`` as given if it exists, else relative to the repository root."""
    p = Path(path)
    if p.exists() or p.is_absolute():
        return p
    return REPO / p


def training_hash(cfg: Mapping[str, Any]) -> str:
    """Identity of a trained model: Stage II config (minus inference keys), the training scenes by
    name and content (:func:`gspi.run.scene_digest.scene_digest`, not by where they lie), seed."""
    stage2 = {k: v for k, v in cfg["stage2"].items() if k not in NOT_TRAINING}
    train_scenes = read_splits(cfg["data_dir"]).get("train", [])
    return config_hash({"stage2": stage2, "train_scenes": scenes_digest(cfg["data_dir"], train_scenes),
                        "seed": cfg["seed"]}, volatile=())


def path_keyed_hash(cfg: Mapping[str, Any]) -> str:
    """The key of caches trained before issue 54 (the dataset's absolute path instead of its
    content): such a model is adopted, not retrained (:func:`adopt_path_keyed`)."""
    stage2 = {k: v for k, v in cfg["stage2"].items() if k not in NOT_TRAINING}
    train_scenes = read_splits(cfg["data_dir"]).get("train", [])
    return config_hash({"stage2": stage2, "train_scenes": train_scenes, "seed": cfg["seed"],
                        "data": str(Path(cfg["data_dir"]).resolve())}, volatile=())


def adopt_path_keyed(cfg: Mapping[str, Any], folder: Path) -> None:
    """Renames a pre-issue-54 cache folder of this very dataset (same path, so same content) to
    the content key ``folder``, so an existing (or half-trained) model is kept. Call under the lock."""
    old = folder.parent / path_keyed_hash(cfg)
    if not folder.exists() and old.is_dir() and (old / "checkpoint.pt").is_file():
        old.rename(folder)
        log.info("Stage II cache %s is now keyed by content: %s", old, folder)


def check_compatible(have, want, path: Path) -> None:
    """The run's ablation switches (``want``, its Stage2Config) must be those the checkpoint
    was trained with (``have``)."""
    pairs = {"stage2.data.local_condition": (have.data.local_condition, want.data.local_condition),
             "stage2.prior.encoder": (have.prior.encoder, want.prior.encoder)}
    bad = {k: v for k, v in pairs.items() if v[0] != v[1]}
    if bad:
        desc = "; ".join(f"{k}: checkpoint {a!r}, run {b!r}" for k, (a, b) in bad.items())
        raise ConfigError(f"{path}: the Stage II checkpoint does not match the run's config ({desc}); "
                         f"set stage2.checkpoint=null to train a matching model")


def load_stage2_context(cfg: Mapping[str, Any], cache_root: Path, stage2=None) -> Stage2Context:
    """The run's :class:`~gspi.pipeline.Stage2Context`: :func:`load_or_train` plus the prior's
    encoder; ``stage2``: the run's checked Stage2Config (parsed from ``cfg`` when not given)."""
    from gspi.stage2.config import complete_stage2
    from gspi.stage2.encoders import build_encoder

    stage2 = complete_stage2(cfg["stage2"] if stage2 is None else stage2)
    model, model_cfg, info = load_or_train(cfg, stage2, cache_root)
    return Stage2Context(model=model, model_cfg=model_cfg, encoder=build_encoder(model_cfg["stage2"].prior),
                         info=info, run_cfg=stage2)


def load_or_train(cfg: Mapping[str, Any], stage2, cache_root: Path):
    """(model in eval mode with EMA weights, the checkpoint's config, info) for the run config
    ``cfg`` whose ``stage2`` node is the checked ``stage2`` (a Stage2Config)."""
    from gspi.stage2.checkpoint import load_stage2_checkpoint
    from gspi.device import resolve_device
    from gspi.stage2.distributed import DistContext
    from gspi.stage2.train import train

    ckpt = stage2.checkpoint
    if ckpt:
        path = resolve_path(ckpt)
        model, saved = load_stage2_checkpoint(path)
        check_compatible(saved["stage2"], stage2, path)
        return model, saved, {"checkpoint": str(path), "trained": False}
    folder = Path(cache_root) / "stage2" / training_hash(cfg)
    train_cfg = {"stage2": replace(stage2, checkpoint=None), "data_dir": str(cfg["data_dir"]),
                 "seed": int(cfg["seed"])}
    with file_lock(folder):
        adopt_path_keyed(cfg, folder)
        done = folder / "checkpoint.pt"
        stats = None
        if not (done.is_file() and _finished(done, train_cfg)):
            log.info("training Stage II into %s", folder)
            stats = train(train_cfg, folder, dist=DistContext(device=resolve_device(cfg.get("device", "cpu"))))
        model, saved = load_stage2_checkpoint(done)
    return model, saved, {"checkpoint": str(done), "trained": stats is not None, "train_stats": stats}


def _finished(path: Path, train_cfg: Mapping[str, Any]) -> bool:
    from gspi.stage2.checkpoint import read_checkpoint

    train = train_cfg["stage2"].train
    last = min(int(train.steps), int(train.stop_at or train.steps))
    return int(read_checkpoint(path)["step"]) >= last
