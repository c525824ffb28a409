"""Stage II configuration (paper, "Geometry-Conditioned Point Cloud Diffusion"): the ``stage2``
node of gspi-train and gspi-run (``conf/stage2/*.yaml``) as one checked dataclass.

``Stage2Config.from_dict`` builds it from a resolved ``stage2`` node and rejects unknown keys,
wrong types and out-of-range values (``gspi.strict_config``), naming the dotted key, at
start-up. ``complete_stage2(node)`` returns it checked, every key present: the one place
where a key missing from a YAML or from an older checkpoint's stored config gets its default.
From there on the stage passes the ``Stage2Config`` itself (``cfg["stage2"]`` of the training
config) and its code reads fields (``stage2.train.steps``, ``stage2.data``): nothing parses the
node a second time. ``stored_config(cfg)`` turns it back into plain data where it is written
(checkpoints, a study's model files).

The denoiser sizes (``stage2.model``) are :class:`~gspi.stage2.model.RCWConfig`'s fields and
defaults; its condition widths, head and schedule length are derived (from ``stage2.data``,
the prior's encoder and ``stage2.diffusion``), so setting them under ``model`` is an error.
Training items are :class:`~gspi.stage2.data.PointDataConfig`, the global prior
:class:`~gspi.stage2.encoders.PriorConfig`, whole-cloud sampling
:class:`~gspi.stage2.infer.InferenceConfig`: each section beside the code it configures.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar, Mapping, Optional

from gspi.stage2.data import LOCAL_CONDITIONS, PointDataConfig
from gspi.stage2.encoders import PriorConfig
from gspi.stage2.infer import InferenceConfig
from gspi.stage2.model import PREDICTIONS, RCWConfig
from gspi.stage2.validate import ValidationConfig
from gspi.strict_config import dataclass_from_dict

# RCWConfig fields that the rest of the config decides (rcw_config in gspi/stage2/train.py)
DERIVED_MODEL_KEYS = ("feature_dim", "local_cond_dim", "use_view_onehot", "global_token_dim",
                      "global_grid_cells", "num_lattice_views", "prediction", "readout_column",
                      "readout_metal_gate", "num_train_timesteps")
MODEL_KEYS = tuple(f.name for f in fields(RCWConfig) if f.name not in DERIVED_MODEL_KEYS)


@dataclass
class DiffusionConfig:
    num_train_timesteps: int = 1000   # cosine schedule length T
    min_snr_gamma: float = 5.0        # Min-SNR-gamma loss weights
    min_snr_floor: float = 0.0        # x0-space weight floor: 0 = Min-SNR (paper), 1 = truncated SNR
    self_condition_prob: float = 0.5  # batches that take the self-conditioning pass
    prediction: str = "eps"           # output head: eps (paper) | x0 (read as eps; docs/STAGE2.md) | x0_readout (docs/LIGHT.md)
    readout_metal_gate: bool = False  # x0_readout: no metal added where the read-out's metallic is 0 (docs/LIGHT.md)

    RANGES: ClassVar[dict] = {"num_train_timesteps": (2, None), "min_snr_gamma": (0.0, None),
                              "min_snr_floor": (0.0, None), "self_condition_prob": (0.0, 1.0)}
    CHOICES: ClassVar[dict] = {"prediction": PREDICTIONS}

    def __post_init__(self) -> None:
        if self.readout_metal_gate and self.prediction != "x0_readout":
            raise ValueError("stage2.diffusion.readout_metal_gate gates the x0_readout head's metallic correction: "
                             f"it needs stage2.diffusion.prediction=x0_readout, got {self.prediction}")
        if self.min_snr_floor > self.min_snr_gamma:
            raise ValueError(f"stage2.diffusion.min_snr_floor={self.min_snr_floor} exceeds "
                             f"min_snr_gamma={self.min_snr_gamma}: the weight is clamp(SNR, floor, gamma)")


@dataclass
class TrainConfig:
    steps: int = 200000
    batch_size: int = 32
    lr: float = 1.0e-4
    min_lr_ratio: float = 0.1         # cosine decay to lr * min_lr_ratio
    warmup_steps: int = 2000
    weight_decay: float = 0.01
    betas: list = field(default_factory=lambda: [0.9, 0.999])
    grad_clip: float = 1.0            # max global gradient norm
    ema_decay: float = 0.9999
    stop_at: Optional[int] = None     # checkpoint and stop after this step (resumable)
    stop_after_minutes: Optional[float] = None  # the same after this many wall-clock minutes
    stop_after_cpu_minutes: Optional[float] = None  # ... or this many minutes of process CPU time
    init_from: Optional[str] = None   # fine-tune from another Stage II checkpoint's EMA weights
    checkpoint_every: int = 5000
    checkpoint_minutes: Optional[float] = 10.0  # ... and after this many wall-clock minutes since the last one
    run_log: Optional[str] = None     # append one JSON line per finished run (chunk) to this file
    log_every: int = 100

    RANGES: ClassVar[dict] = {"steps": (1, None), "batch_size": (1, None), "lr": (0.0, None),
                              "min_lr_ratio": (0.0, 1.0), "warmup_steps": (0, None),
                              "weight_decay": (0.0, None), "grad_clip": (0.0, None),
                              "ema_decay": (0.0, 1.0), "stop_at": (0, None),
                              "stop_after_minutes": (0.0, None), "stop_after_cpu_minutes": (0.0, None),
                              "checkpoint_every": (1, None), "checkpoint_minutes": (0.0, None),
                              "log_every": (1, None)}

    def __post_init__(self) -> None:
        if len(self.betas) != 2 or not all(0.0 <= float(b) < 1.0 for b in self.betas):
            raise ValueError(f"stage2.train.betas={self.betas!r}: must be two numbers in [0, 1)")


@dataclass
class PointsEvalConfig:
    """After gspi-train: Table 2's measure on the point clouds of a split."""

    enabled: bool = True
    split: str = "test"
    num_steps: int = 50               # DDIM steps (paper: 50)
    seed: int = 0
    write_chunk: Optional[int] = 32768

    RANGES: ClassVar[dict] = {"num_steps": (1, None), "seed": (0, None), "write_chunk": (1, None)}
    CHOICES: ClassVar[dict] = {"split": ("train", "val", "test")}


@dataclass
class Stage2Config:
    model: dict = field(default_factory=dict)  # RCWConfig sizes (MODEL_KEYS)
    diffusion: DiffusionConfig = field(default_factory=DiffusionConfig)
    prior: PriorConfig = field(default_factory=PriorConfig)
    data: PointDataConfig = field(default_factory=PointDataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    checkpoint: Optional[str] = None  # gspi-run: a trained model; null = train this config
    inference: InferenceConfig = field(default_factory=InferenceConfig)
    eval: PointsEvalConfig = field(default_factory=PointsEvalConfig)
    validate: ValidationConfig = field(default_factory=ValidationConfig)

    def __post_init__(self) -> None:
        if self.data.local_condition not in LOCAL_CONDITIONS:
            raise ValueError(f"stage2.data.local_condition={self.data.local_condition!r}: must be "
                             f"one of {sorted(LOCAL_CONDITIONS)}")
        if self.data.needs_feature_maps and self.prior.encoder == "none":
            key = "pixel_features" if self.data.pixel_features else "pixel_feature_spread"
            raise ValueError(f"stage2.data.{key} samples the prior encoder's map: it needs "
                             "stage2.prior.encoder alexnet or dinov2, not none (A1)")
        self.model = model_sizes(self.model)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> "Stage2Config":
        return dataclass_from_dict(cls, values, "stage2")


def model_sizes(model: Mapping[str, Any]) -> dict:
    """``stage2.model`` checked against RCWConfig (types, head divisibility) and completed with
    its defaults; derived keys are refused, naming what decides them."""
    derived = sorted(set(model) & set(DERIVED_MODEL_KEYS))
    if derived:
        raise ValueError(f"stage2.model.{derived[0]} is derived, not set: the condition widths follow "
                         "stage2.data.local_condition and stage2.prior.encoder, the head and schedule "
                         f"stage2.diffusion (derived keys: {list(DERIVED_MODEL_KEYS)})")
    sizes = dataclass_from_dict(RCWConfig, dict(model), "stage2.model")
    return {k: getattr(sizes, k) for k in MODEL_KEYS}


def complete_stage2(node: "Mapping[str, Any] | Stage2Config") -> Stage2Config:
    """The ``stage2`` node checked, with every key (defaults filled in); a Stage2Config is
    returned as it is."""
    return node if isinstance(node, Stage2Config) else Stage2Config.from_dict(node)


def stored_config(cfg: Mapping[str, Any]) -> dict:
    """``cfg`` as plain data (``stage2`` a dict) for a file: a checkpoint's ``config``."""
    stage2 = cfg.get("stage2")
    return {**cfg, "stage2": asdict(stage2)} if isinstance(stage2, Stage2Config) else dict(cfg)
