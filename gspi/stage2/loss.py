"""Stage II training objective (paper Sec. "Multi-Scale Cross-View Conditioning": eps-prediction
DDPM loss with a cosine schedule and Min-SNR-gamma reweighting).

    t ~ U{0, T-1} per sample,  eps ~ N(0, I),  f_t = q_sample(f0, t, eps)
    loss = mean_b [ w(t_b) * mean_{n,c} (eps_hat - eps)^2 ],  w = min(SNR, gamma) / SNR
                                            (floor > 0: w = clamp(SNR, floor, gamma) / SNR)

plus the two PointInfinity/RIN training tricks (method-notes 1.1, 1.3): conditions dropped
with probability ``config.cond_drop_prob`` per sample (for classifier-free guidance), and
latent self-conditioning with probability ``self_condition_prob`` per batch (a no-grad first
pass whose final latents, detached, feed the graded pass).
"""
from __future__ import annotations

from typing import Optional

import torch
from torch import Tensor

from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import RCWDenoiser
from gspi.stage2.sampler import sample_noise
from gspi.stage2.schedule import MIN_SNR_GAMMA, cosine_alphas_cumprod, min_snr_eps_weights, q_sample


def _uniform(shape: tuple[int, ...], generator: Optional[torch.Generator], device: torch.device) -> Tensor:
    gen_device = generator.device if generator is not None else device
    return torch.rand(shape, generator=generator, device=gen_device).to(device)


def denoising_loss(
    model: RCWDenoiser,
    f0: Tensor,  # [B, N, 5] clean features in [-1, 1]
    inputs: Stage2Inputs,
    *,
    generator: Optional[torch.Generator] = None,
    alphas_cumprod: Optional[Tensor] = None,  # [T]; None = cosine, T = 1000
    min_snr_gamma: float = MIN_SNR_GAMMA,
    min_snr_floor: float = 0.0,
    self_condition_prob: float = 0.5,
    shard: Optional[tuple[int, int]] = None,
) -> Tensor:
    """Min-SNR-weighted eps-prediction loss of one batch (module docstring).

    Args:
        shard: ``(rank, world_size)`` when ``f0`` is one rank's slice of a global batch of
            ``world_size * B`` (gspi.stage2.distributed): t, eps and the condition drops are
            drawn for the global batch and sliced, so the ranks together see one process's draws.
    Returns:
        scalar loss (graded w.r.t. the model parameters).
    """
    alphas_cumprod = cosine_alphas_cumprod() if alphas_cumprod is None else alphas_cumprod
    b, device = f0.shape[0], f0.device
    rank, world = shard or (0, 1)
    mine, gb = slice(rank * b, (rank + 1) * b), b * world  # this rank's rows of the global batch
    t = (_uniform((gb,), generator, device) * len(alphas_cumprod)).long().clamp(max=len(alphas_cumprod) - 1)[mine]
    eps = sample_noise((gb, *f0.shape[1:]), generator=generator, device=device, dtype=f0.dtype)[mine]
    f_t = q_sample(f0, t, eps, alphas_cumprod=alphas_cumprod)
    cond_keep = (_uniform((gb,), generator, device) >= model.config.cond_drop_prob)[mine]
    prev_latents = None
    if model.config.self_condition and float(_uniform((1,), generator, device)) < self_condition_prob:
        with torch.no_grad():
            prev_latents = model(f_t, t, inputs, cond_keep=cond_keep).latents.detach()
    eps_hat = model(f_t, t, inputs, prev_latents=prev_latents, cond_keep=cond_keep).eps
    per_sample = (eps_hat - eps).pow(2).mean(dim=(1, 2))  # [B]
    weights = min_snr_eps_weights(t, gamma=min_snr_gamma, floor=min_snr_floor, alphas_cumprod=alphas_cumprod)
    return (weights * per_sample).mean()
