"""Stage III hyperparameters (paper, "Distilling PBR Attributes onto Gaussian Primitives").

``Stage3Config.from_dict`` builds the config from plain nested dicts (a resolved Hydra
``stage3`` node) and rejects unknown keys (``gspi.strict_config``). The
Table 3 ablations are switches: A6 ``distill: false``, A7 ``freeze_opacity: true``, A8
``freeze_scales: true``, A9 both (``conf/ablation/a6_*.yaml`` .. ``a9_*.yaml``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar, Optional

from gspi.strict_config import dataclass_from_dict

FALLBACKS = ("nearest", "mean")
SH_MODES = ("channel", "scalar", "chroma")


@dataclass
class InitConfig:
    depth_tolerance_px: float = 2.0   # |z_centre - median depth| allowed, in pixel footprints z / fx
    sh_harmonize: float = 1.0         # beta: albedo = (1 - beta) gathered + beta * S(gathered, SH-DC colour)
    sh_gain: str = "chroma"           # S: per-channel gain | scalar gain | chroma (docs/STAGE3.md)
    harmonize_targets: bool = True    # the staged albedo targets get the same blend (distillation keeps it)
    fallback: str = "nearest"         # Gaussians without a valid sample: nearest initialised | mean
    logit_eps: float = 1e-3           # values clamped to [eps, 1 - eps] before the logit


@dataclass
class PropertyWeights:
    albedo: float = 1.0               # paper (w_a, w_r, w_m) = (1, 1, 3)
    roughness: float = 1.0
    metallic: float = 3.0             # up-weighted: near-binary metallic maps give sparse gradients


@dataclass
class LossConfig:
    ssim_lambda: float = 0.2          # lambda in (1 - lambda)(L1 + L2) / 2 + lambda (1 - SSIM)
    weights: PropertyWeights = field(default_factory=PropertyWeights)
    silhouette_threshold: float = 0.5  # B_v = rendered alpha of the input asset >= this


@dataclass
class LrConfig:
    pbr: float = 2.0e-2               # Adam lr of the albedo / roughness / metallic logits
    opacities: float = 5.0e-3         # conservative: a tenth of Stage 0's 5e-2
    scales: float = 1.0e-3            # conservative: a fifth of Stage 0's 5e-3 (log scales)
    final_factor: float = 0.1         # every lr decays exponentially to this fraction


@dataclass
class Stage3Config:
    name: str = "default"
    iterations: int = 500
    distill: bool = True              # False = A6: initialisation only
    freeze_opacity: bool = False      # A7
    freeze_scales: bool = False       # A8 (A9: both)
    views_per_iteration: int = 1      # lattice views rendered per step (a fresh permutation per epoch)
    seed: int = 0
    log_every: int = 25               # record the loss every this many iterations
    plateau_tol: Optional[float] = None  # stop at an epoch's end once its mean loss fell by less than this
    #                                       fraction of the previous epoch's (None: run every iteration)
    backend: str = "auto"             # rasterizer backend: auto | torch | numba | gsplat
    init: InitConfig = field(default_factory=InitConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    lr: LrConfig = field(default_factory=LrConfig)

    # Allowed values, checked by gspi.strict_config at start-up (inclusive; None = open).
    RANGES: ClassVar[dict] = {"iterations": (0, None),
                              "views_per_iteration": (1, None), "seed": (0, None), "log_every": (1, None),
                              "plateau_tol": (0.0, 1.0)}
    CHOICES: ClassVar[dict] = {"backend": ("auto", "torch", "numba", "gsplat")}

    def __post_init__(self) -> None:
        if self.init.fallback not in FALLBACKS:
            raise ValueError(f"stage3.init.fallback must be one of {FALLBACKS}, got {self.init.fallback!r}")
        if self.init.sh_gain not in SH_MODES:
            raise ValueError(f"stage3.init.sh_gain must be one of {SH_MODES}, got {self.init.sh_gain!r}")
        if not 0.0 <= self.init.sh_harmonize <= 1.0:
            raise ValueError(f"stage3.init.sh_harmonize must be in [0, 1], got {self.init.sh_harmonize}")
        if not 0.0 <= self.loss.ssim_lambda <= 1.0:
            raise ValueError(f"stage3.loss.ssim_lambda must be in [0, 1], got {self.loss.ssim_lambda}")
        if self.iterations < 0 or self.views_per_iteration < 1:
            raise ValueError("stage3.iterations must be >= 0 and stage3.views_per_iteration >= 1")

    @classmethod
    def from_dict(cls, data: dict) -> "Stage3Config":
        """Builds the config from plain nested dicts; unknown keys raise ``ValueError``."""
        return dataclass_from_dict(cls, dict(data), "stage3")

    def to_dict(self) -> dict:
        """Plain nested dict (round-trips through :meth:`from_dict`)."""
        return asdict(self)

    @property
    def weights(self) -> dict[str, float]:
        """Property weights w_p as {"albedo", "roughness", "metallic"} -> float."""
        return asdict(self.loss.weights)
