"""The learnability ladder's direct regressors (docs/log/stage2.md "Where the signal is lost").

Each rung of the ladder predicts the clean PBR features f0 in [-1, 1] of every point in one
forward pass, from a stated set of inputs, so that its gain or loss against the next rung says
which part of Stage II loses what:

* ``r1`` a per-point MLP on the local condition alone (Top-RGB + view one-hot, 35 dims);
* ``r2`` R1 + the scene's global prior features, mean-pooled over views and cells (D dims);
* ``r3`` R1 + every lattice view's sRGB and visibility at the point (A5's condition, 128 dims);
* ``r4`` the RCW backbone (``RCWDenoiser``, the Stage II architecture) trained as a regressor:
  the noisy-feature input is all zeros and the timestep fixed at ``T - 1``, no self-conditioning,
  no condition dropout; its raw head is read as f0.

R0 (no decomposition) and R5 (the RCW diffusion, today's Full) are the existing baseline and
model (``gspi.stage2.evaluate_points``); ``experiments.ladder.ladder`` trains and scores them all.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from torch import Tensor, nn

from gspi.stage2.data import ScenePoints, local_condition, local_condition_dim
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import RCWConfig, RCWDenoiser

MLP_RUNGS = {"r1": ("top_rgb_onehot",), "r2": ("top_rgb_onehot",), "r3": ("top_rgb_onehot", "multiview")}


@dataclass(frozen=True)
class PointFeatures:
    """What a per-point rung reads: local conditions (concatenated) and optionally the pooled prior."""

    conditions: tuple[str, ...]
    pooled_prior: bool = False

    def width(self, prior_dim: int) -> int:
        return sum(local_condition_dim(c) for c in self.conditions) + (prior_dim if self.pooled_prior else 0)


def rung_features(rung: str) -> PointFeatures:
    if rung not in MLP_RUNGS:
        raise ValueError(f"rung {rung!r} is not a per-point MLP rung; those are {sorted(MLP_RUNGS)}")
    return PointFeatures(conditions=MLP_RUNGS[rung], pooled_prior=rung == "r2")


def pooled_prior(scene: ScenePoints) -> Tensor:
    """[D] mean of the scene's global prior tokens over all views and cells."""
    if scene.global_tokens is None:
        raise ValueError(f"scene {scene.name}: rung r2 needs the global prior (stage2.prior.encoder != none)")
    return scene.global_tokens.float().mean(dim=(0, 1))


def point_features(scene: ScenePoints, idx: np.ndarray, xyz_perturbed: np.ndarray, spec: PointFeatures,
                   *, tol_pixels: float) -> Tensor:
    """[n, C] features of points ``idx`` (perturbed positions ``xyz_perturbed``) for a per-point rung."""
    parts = [torch.from_numpy(local_condition(scene, idx, xyz_perturbed, c, tol_pixels=tol_pixels)
                              .astype(np.float32)) for c in spec.conditions]
    if spec.pooled_prior:
        parts.append(pooled_prior(scene).expand(len(idx), -1))
    return torch.cat(parts, dim=1)


class PointMLP(nn.Module):
    """Per-point MLP: [..., C] features -> [..., 5] f0 estimate (LayerNorm'd input, GELU)."""

    def __init__(self, in_dim: int, hidden: int = 256, depth: int = 4, out_dim: int = 5):
        super().__init__()
        layers: list[nn.Module] = [nn.LayerNorm(in_dim)]
        width = in_dim
        for _ in range(depth - 1):
            layers += [nn.Linear(width, hidden), nn.GELU()]
            width = hidden
        layers.append(nn.Linear(width, out_dim))
        self.net = nn.Sequential(*layers)

    def forward(self, features: Tensor) -> Tensor:
        return self.net(features)


class RCWRegressor(nn.Module):
    """The RCW denoiser as a one-pass regressor of f0 (rung R4): f_t = 0 at t = T - 1."""

    def __init__(self, config: RCWConfig):
        super().__init__()
        self.denoiser = RCWDenoiser(config)

    @property
    def config(self) -> RCWConfig:
        return self.denoiser.config

    def forward(self, inputs: Stage2Inputs, write_chunk: Optional[int] = None) -> Tensor:
        b, n = inputs.xyz.shape[:2]
        f_t = inputs.xyz.new_zeros(b, n, self.config.feature_dim)
        t = torch.full((b,), self.config.num_train_timesteps - 1, dtype=torch.long, device=inputs.xyz.device)
        head, _ = self.denoiser.head(f_t, t, inputs, write_chunk=write_chunk)
        return head


def regression_loss(pred: Tensor, f0: Tensor) -> Tensor:
    """Mean squared error in the model space [-1, 1] over all points and channels."""
    return torch.mean((pred - f0) ** 2)

