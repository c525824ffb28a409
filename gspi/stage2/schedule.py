"""Noise schedule of Stage II's feature-only diffusion (paper Sec. "Geometry-Conditioned,
Feature-Only Diffusion", Eq. feature_forward; cosine schedule + Min-SNR-gamma weighting).

Decision: our own implementation, not diffusers' schedulers. The math is ~60 lines of
closed-form formulas (below), while diffusers pulls in huggingface-hub, safetensors and
requests at import, and its ``DDIMScheduler.step`` takes ONE timestep for the whole batch
(training here draws one timestep per sample) and keeps the schedule in float32. diffusers
stays the test oracle without being installed: ``tests/golden/record_oracles.py`` ran
``DDIMScheduler(beta_schedule="squaredcos_cap_v2", timestep_spacing="trailing")`` once and
``tests/test_stage2_schedule.py`` checks ``alphas_cumprod``, the timesteps, ``add_noise`` and four
full DDIM loops against its recorded outputs (``tests/golden/diffusers_ddim.json``).

Formulas (Nichol & Dhariwal 2021; diffusers ``betas_for_alpha_bar``, "squaredcos_cap_v2"):

    g(tau)        = cos^2((tau + 0.008) / 1.008 * pi / 2)
    beta_i        = min(1 - g((i + 1) / T) / g(i / T), 0.999),   i = 0 .. T-1
    alpha_bar_i   = prod_{j <= i} (1 - beta_j)
    f_t           = sqrt(alpha_bar_t) f_0 + sqrt(1 - alpha_bar_t) eps          (q_sample)
    SNR_t         = alpha_bar_t / (1 - alpha_bar_t)
    w_t (eps)     = min(SNR_t, gamma) / SNR_t                                  (Min-SNR-gamma)
    w_t (eps)     = clamp(SNR_t, floor, gamma) / SNR_t      (floor > 0: truncated SNR, below)

In x0 terms the eps error is ``SNR_t`` times the x0 error, so Min-SNR weighs the x0 error by
``min(SNR_t, gamma)``: ~0 at the noisy end (SNR_999 ~ 2e-9), where DDIM's first step reads the
model's x0. A floor (Salimans & Ho 2022's "truncated SNR", ``max(SNR, 1)``) keeps that weight
at ``floor``; ``floor = 0`` is the paper's Min-SNR exactly.

The schedule is kept in float64 (diffusers: float32); values are cast to the sample dtype
where they meet tensors. Timesteps are 0-based integer indices ``t`` in ``[0, T)``.
"""
from __future__ import annotations

import math
from typing import Optional

import torch
from torch import Tensor

NUM_TRAIN_TIMESTEPS = 1000
MIN_SNR_GAMMA = 5.0


def cosine_betas(num_train_timesteps: int = NUM_TRAIN_TIMESTEPS, *, max_beta: float = 0.999) -> Tensor:
    """Cosine-schedule betas, diffusers' ``squaredcos_cap_v2``.

    Returns:
        [T] float64, ``beta_i = min(1 - g((i+1)/T) / g(i/T), max_beta)``.
    """
    def g(tau: Tensor) -> Tensor:
        return torch.cos((tau + 0.008) / 1.008 * math.pi / 2) ** 2

    i = torch.arange(num_train_timesteps, dtype=torch.float64)
    betas = 1.0 - g((i + 1) / num_train_timesteps) / g(i / num_train_timesteps)
    return betas.clamp(max=max_beta)


def cosine_alphas_cumprod(num_train_timesteps: int = NUM_TRAIN_TIMESTEPS) -> Tensor:
    """``alpha_bar_i = prod_{j<=i} (1 - beta_j)`` of :func:`cosine_betas`.

    For T = 1000: alpha_bar_0 = 1 - 4e-5, alpha_bar_500 = 0.492, alpha_bar_999 = 2.4e-9.

    Returns:
        [T] float64, decreasing from ~1 to ~0.
    """
    return torch.cumprod(1.0 - cosine_betas(num_train_timesteps), dim=0)


def _schedule(alphas_cumprod: Optional[Tensor]) -> Tensor:
    return cosine_alphas_cumprod() if alphas_cumprod is None else alphas_cumprod


def _gather(values: Tensor, t: Tensor | int, like: Tensor) -> Tensor:
    """``values[t]`` shaped to broadcast against ``like`` [B, ...] (t: int or [B])."""
    t = torch.as_tensor(t, device=values.device, dtype=torch.long)
    out = values[t].to(device=like.device, dtype=like.dtype)
    return out.reshape(out.shape + (1,) * (like.dim() - out.dim()))


def q_sample(
    f0: Tensor,  # [B, N, C] clean features in [-1, 1]
    t: Tensor | int,  # [B] or scalar int timestep indices
    eps: Tensor,  # [B, N, C] standard normal noise
    *,
    alphas_cumprod: Optional[Tensor] = None,  # [T]; None = cosine, T = 1000
) -> Tensor:
    """Forward process ``f_t = sqrt(ab_t) f0 + sqrt(1 - ab_t) eps`` (diffusers ``add_noise``).

    Returns:
        [B, N, C] noisy features ``f_t``.
    """
    ab = _gather(_schedule(alphas_cumprod), t, f0)
    return ab.sqrt() * f0 + (1.0 - ab).sqrt() * eps


def f0_from_eps(f_t: Tensor, eps: Tensor, alpha_bar: Tensor | float) -> Tensor:
    """``f0 = (f_t - sqrt(1 - ab) eps) / sqrt(ab)``: the one eps -> x0 conversion (inverse of q_sample).

    Args:
        f_t: [B, N, C] noisy features; eps: [B, N, C] (predicted) noise.
        alpha_bar: ab_t as a float or a tensor broadcasting against ``f_t`` (e.g. [B, 1, 1]).
    Returns:
        [B, N, C] clean-feature estimate (unclipped).
    """
    return (f_t - (1.0 - alpha_bar) ** 0.5 * eps) / alpha_bar ** 0.5


def eps_from_f0(f_t: Tensor, f0: Tensor, alpha_bar: Tensor | float) -> Tensor:
    """``eps = (f_t - sqrt(ab) f0) / sqrt(1 - ab)``: the one x0 -> eps conversion.

    Used after x0 clipping (GLIDE style) and to read an x0-predicting head as eps.

    Args:
        f_t: [B, N, C] noisy features; f0: [B, N, C] clean-feature estimate.
        alpha_bar: ab_t as a float or a tensor broadcasting against ``f_t`` (e.g. [B, 1, 1]).
    Returns:
        [B, N, C] noise consistent with ``f0``.
    """
    return (f_t - alpha_bar ** 0.5 * f0) / (1.0 - alpha_bar) ** 0.5


def predict_f0_from_eps(
    f_t: Tensor,  # [B, N, C] noisy features
    t: Tensor | int,  # [B] or scalar int
    eps: Tensor,  # [B, N, C] (predicted) noise
    *,
    alphas_cumprod: Optional[Tensor] = None,
) -> Tensor:
    """:func:`f0_from_eps` at timestep indices ``t`` of the schedule.

    Returns:
        [B, N, C] clean-feature estimate (unclipped).
    """
    return f0_from_eps(f_t, eps, _gather(_schedule(alphas_cumprod), t, f_t))


def predict_eps_from_f0(
    f_t: Tensor,  # [B, N, C]
    t: Tensor | int,  # [B] or scalar int
    f0: Tensor,  # [B, N, C]
    *,
    alphas_cumprod: Optional[Tensor] = None,
) -> Tensor:
    """:func:`eps_from_f0` at timestep indices ``t`` of the schedule.

    Returns:
        [B, N, C] noise consistent with ``f0``.
    """
    return eps_from_f0(f_t, f0, _gather(_schedule(alphas_cumprod), t, f_t))


def snr(t: Tensor | int, *, alphas_cumprod: Optional[Tensor] = None) -> Tensor:
    """Signal-to-noise ratio ``ab_t / (1 - ab_t)`` (diffusers ``training_utils.compute_snr``).

    Returns:
        float64 tensor with the shape of ``t``.
    """
    schedule = _schedule(alphas_cumprod)
    ab = schedule[torch.as_tensor(t, dtype=torch.long, device=schedule.device)]
    return ab / (1.0 - ab)


def min_snr_eps_weights(
    t: Tensor,  # [B] int timesteps
    *,
    gamma: float = MIN_SNR_GAMMA,
    floor: float = 0.0,
    alphas_cumprod: Optional[Tensor] = None,
) -> Tensor:
    """Min-SNR-gamma loss weights for eps prediction (Hang et al. 2023): ``min(SNR, gamma) / SNR``;
    with ``floor > 0``, ``clamp(SNR, floor, gamma) / SNR`` (the x0-space weight never below
    ``floor``; module docstring).

    Min-SNR: 1 where SNR < gamma (for the T = 1000 cosine schedule: t >= 261), ``gamma / SNR``
    else; with floor 1 also ``1 / SNR`` where SNR < 1 (t >= 496).

    Returns:
        [B] float32 weights, on the device of ``t``.
    """
    if not 0.0 <= floor <= gamma:
        raise ValueError(f"Min-SNR floor {floor} must lie in [0, gamma = {gamma}]")
    s = snr(t, alphas_cumprod=alphas_cumprod)
    return (s.clamp(min=floor, max=gamma) / s).float().to(torch.as_tensor(t).device)


def ddim_timesteps(num_steps: int, num_train_timesteps: int = NUM_TRAIN_TIMESTEPS) -> Tensor:
    """DDIM timesteps with "trailing" spacing (diffusers ``timestep_spacing="trailing"``).

    ``round(arange(T, 0, -T / S)) - 1``: for T = 1000, S = 50 gives 999, 979, ..., 19, so
    sampling starts at the pure-noise end (the "leading" default never visits t = 999).

    Returns:
        [S] int64, strictly decreasing.
    """
    if not 1 <= num_steps <= num_train_timesteps:
        raise ValueError(f"num_steps must be in [1, {num_train_timesteps}], got {num_steps}")
    steps = torch.arange(num_train_timesteps, 0, -num_train_timesteps / num_steps, dtype=torch.float64)
    return steps.round().long() - 1
