"""Structured config of the evaluation protocol (`conf/eval/*.yaml` validates against it).

Every choice a reviewer may question is a field here; docs/PROTOCOL.md explains each default.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from hydra.core.config_store import ConfigStore

# Absolute path of the repository's conf/: console-script entry points make Hydra resolve a
# relative config_path as a Python package, which conf/ is not.
CONF_DIR = str(Path(__file__).resolve().parents[1] / "conf")


@dataclass
class LpipsConfig:
    net: str = "alex"            # AlexNet LPIPS, the network the field reports
    version: str = "0.1"         # linear-head version of PerceptualSimilarity
    mode: str = "masked_mean"    # masked_mean | composite (see eval/metrics.py)


@dataclass
class RelightConfig:
    envs: list[str] | None = None       # None = the scene's held-out relight_envs
    tonemap: str = "aces"               # clamp | aces | reinhard, applied to linear radiance
    exposure_stops: float = 0.0         # 2**stops before the tone curve
    srgb: bool = True                   # sRGB-encode after the tone curve
    # A method that does not model a channel is relit with this constant (stated per table).
    fill_roughness: float = 1.0
    fill_metallic: float = 0.0
    apply_albedo_alignment: bool = True  # relight with the aligned albedo when aligning


@dataclass
class ProtocolConfig:
    name: str = "gspi-decoupled"
    version: int = 1
    split: str = "test"                 # which view split of each scene is scored
    channels: list[str] = field(default_factory=lambda: ["albedo", "roughness", "metallic",
                                                         "relight"])
    background: float = 0.0             # composite value outside the mask for SSIM/LPIPS
    albedo_alignment: str = "none"      # none | scale | per_channel (least squares, linear)
    alignment_scope: str = "scene"      # scene (pooled over its views) | view
    fail_on_missing_view: bool = False  # False: report missing views and score the rest
    lpips: LpipsConfig = field(default_factory=LpipsConfig)
    relight: RelightConfig = field(default_factory=RelightConfig)


ALIGNMENTS = ("none", "scale", "per_channel")
SCOPES = ("scene", "view")
CHANNELS = ("albedo", "roughness", "metallic", "relight")


def validate_protocol(cfg) -> None:
    """Raise ValueError naming the field when a protocol value is not allowed."""
    if cfg.albedo_alignment not in ALIGNMENTS:
        raise ValueError(f"eval.albedo_alignment={cfg.albedo_alignment!r}; allowed: {ALIGNMENTS}")
    if cfg.alignment_scope not in SCOPES:
        raise ValueError(f"eval.alignment_scope={cfg.alignment_scope!r}; allowed: {SCOPES}")
    bad = [c for c in cfg.channels if c not in CHANNELS]
    if bad:
        raise ValueError(f"eval.channels has unknown {bad}; allowed: {CHANNELS}")
    if not cfg.channels:  # would score nothing and exit 0 with an empty summary
        raise ValueError(f"eval.channels=[]: must name at least one of {CHANNELS}")
    # the composite value outside the mask enters SSIM and LPIPS: a display value in [0, 1]
    background = cfg.background
    if isinstance(background, bool) or not isinstance(background, (int, float)) or not 0.0 <= background <= 1.0:
        raise ValueError(f"eval.background={background!r}: must be a number in [0, 1]")
    if isinstance(cfg.version, bool) or not isinstance(cfg.version, int) or cfg.version < 1:
        raise ValueError(f"eval.version={cfg.version!r}: must be an integer >= 1")
    if not isinstance(cfg.split, str) or not cfg.split:
        raise ValueError(f"eval.split={cfg.split!r}: must be a split name (train, val or test)")
    if cfg.lpips.net != "alex" or str(cfg.lpips.version) != "0.1":
        raise ValueError("eval.lpips: only net=alex, version=0.1 is available offline")


def register_configs() -> None:
    ConfigStore.instance().store(group="eval", name="base_eval", node=ProtocolConfig)
