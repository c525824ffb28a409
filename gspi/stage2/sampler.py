"""DDIM sampling of Stage II's PBR features (paper Sec. "Training vs. Inference Dynamics":
start from f_T ~ N(0, I), 50 DDIM steps over the whole point cloud).

DDIM (Song et al. 2021, Eq. 12; diffusers ``DDIMScheduler.step``), per step t -> t_prev:

    f0_hat   = (f_t - sqrt(1 - ab_t) eps_hat) / sqrt(ab_t),  clipped to [-1, 1] if clip_sample
    sigma    = eta * sqrt((1 - ab_prev) / (1 - ab_t)) * sqrt(1 - ab_t / ab_prev)
    f_prev   = sqrt(ab_prev) f0_hat + sqrt(1 - ab_prev - sigma^2) eps_hat + sigma z
    ab_prev  = 1 after the last step (diffusers ``set_alpha_to_one=True``)

Classifier-free guidance: ``eps_hat = eps_u + s (eps_c - eps_u)`` with a separate
self-conditioning latent stream per branch (method-notes 1.3). Timesteps use "trailing"
spacing; t_prev is the next timestep of the list (diffusers uses ``t - T // S``, the same
whenever S divides T).
"""
from __future__ import annotations

from typing import Optional, Protocol

import numpy as np
import torch
from torch import Tensor

from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import DenoiserOutput, RCWDenoiser
from gspi.stage2.normalize import SphereFrame, fit_unit_sphere, pbr_from_model, to_unit_sphere
from gspi.stage2.patches import blend_patches, blend_weights, cover_patches, patch_batches
from gspi.stage2.schedule import cosine_alphas_cumprod, ddim_timesteps, eps_from_f0, f0_from_eps

FEATURE_DIM = 5


class Denoiser(Protocol):
    def __call__(self, f_t: Tensor, t: Tensor, inputs: Stage2Inputs, *, prev_latents: Optional[Tensor],
                 cond_keep: Optional[Tensor], write_chunk: Optional[int]) -> DenoiserOutput: ...


def sample_noise(shape: tuple[int, ...], *, generator: Optional[torch.Generator],
                 device: torch.device, dtype: torch.dtype = torch.float32) -> Tensor:
    """Standard normal noise drawn on the generator's device (any device if None), moved to ``device``."""
    gen_device = generator.device if generator is not None else device
    return torch.randn(shape, generator=generator, device=gen_device, dtype=dtype).to(device)


def ddim_step(
    f_t: Tensor,  # [B, N, C] current sample
    eps_hat: Tensor,  # [B, N, C] predicted noise
    ab_t: float,  # alpha_bar at t
    ab_prev: float,  # alpha_bar at t_prev (1.0 after the last step)
    *,
    eta: float = 0.0,
    clip_sample: bool = True,
    use_clipped_model_output: bool = False,
    generator: Optional[torch.Generator] = None,
) -> tuple[Tensor, Tensor]:
    """One DDIM update (module docstring).

    Args:
        use_clipped_model_output: re-derive eps from the clipped f0_hat (GLIDE); diffusers'
            default (False) keeps the network's eps for the direction term.
    Returns:
        (f_prev [B, N, C], f0_hat [B, N, C]).
    """
    f0_hat = f0_from_eps(f_t, eps_hat, ab_t)
    if clip_sample:
        f0_hat = f0_hat.clamp(-1.0, 1.0)
        if use_clipped_model_output:
            eps_hat = eps_from_f0(f_t, f0_hat, ab_t)
    sigma = eta * ((1.0 - ab_prev) / (1.0 - ab_t)) ** 0.5 * (1.0 - ab_t / ab_prev) ** 0.5
    f_prev = ab_prev ** 0.5 * f0_hat + (1.0 - ab_prev - sigma ** 2) ** 0.5 * eps_hat
    if eta > 0:
        f_prev = f_prev + sigma * sample_noise(tuple(f_t.shape), generator=generator,
                                               device=f_t.device, dtype=f_t.dtype)
    return f_prev, f0_hat


@torch.no_grad()
def ddim_sample(
    model: Denoiser,
    cond: Stage2Inputs,
    num_steps: int = 50,
    generator: Optional[torch.Generator] = None,
    *,
    guidance_scale: float = 1.0,
    eta: float = 0.0,
    clip_sample: bool = True,
    use_clipped_model_output: bool = False,
    self_condition: Optional[bool] = None,
    write_chunk: Optional[int] = None,
    alphas_cumprod: Optional[Tensor] = None,
    noise: Optional[Tensor] = None,
) -> Tensor:
    """Samples PBR features for every point of ``cond`` with DDIM.

    Args:
        model: eps-prediction denoiser (:class:`gspi.stage2.model.RCWDenoiser`).
        cond: the frozen geometry and conditions (all N points, all views).
        num_steps: DDIM steps S ("trailing" timesteps 999, 979, ... for S = 50).
        generator: seeds f_T (and the eta > 0 noise) for determinism.
        guidance_scale: CFG scale s; 1 runs the conditional branch only.
        eta: 0 = deterministic DDIM, 1 = DDPM-like.
        clip_sample: clamp f0_hat to [-1, 1] (the features' range) at every step.
        use_clipped_model_output: see :func:`ddim_step`.
        self_condition: feed each step's latents to the next; None = ``model.config.self_condition``.
        write_chunk: points per Write chunk (bounds memory at large N).
        alphas_cumprod: [T] schedule; None = cosine, T = 1000.
        noise: [B, N, 5] f_T to start from instead of drawing it.
    Returns:
        [B, N, 5] sampled features in the model space ([-1, 1] when clip_sample);
        ``gspi.stage2.normalize.pbr_from_model`` maps them to PBR values.
    """
    alphas_cumprod = cosine_alphas_cumprod() if alphas_cumprod is None else alphas_cumprod
    if self_condition is None:
        self_condition = getattr(getattr(model, "config", None), "self_condition", False)
    device = cond.xyz.device
    shape = (cond.batch_size, cond.num_points, FEATURE_DIM)
    f_t = noise.to(device) if noise is not None else sample_noise(shape, generator=generator, device=device)
    timesteps = ddim_timesteps(num_steps, len(alphas_cumprod)).tolist()
    branches: dict[str, Optional[Tensor]] = {"cond": None}  # name -> cond_keep
    if guidance_scale != 1.0:
        branches["uncond"] = torch.zeros(cond.batch_size, device=device)
    prev_latents: dict[str, Optional[Tensor]] = {name: None for name in branches}
    for i, t in enumerate(timesteps):
        t_batch = torch.full((cond.batch_size,), t, device=device, dtype=torch.long)
        eps = {}
        for name, keep in branches.items():
            out = model(f_t, t_batch, cond, prev_latents=prev_latents[name],
                        cond_keep=keep, write_chunk=write_chunk)
            eps[name] = out.eps
            prev_latents[name] = out.latents if self_condition else None
        eps_hat = eps["cond"]
        if guidance_scale != 1.0:
            eps_hat = eps["uncond"] + guidance_scale * (eps["cond"] - eps["uncond"])
        ab_prev = float(alphas_cumprod[timesteps[i + 1]]) if i + 1 < len(timesteps) else 1.0
        f_t, _ = ddim_step(f_t, eps_hat, float(alphas_cumprod[t]), ab_prev, eta=eta, clip_sample=clip_sample,
                           use_clipped_model_output=use_clipped_model_output, generator=generator)
    return f_t


@torch.no_grad()
def predict_point_pbr(
    model: RCWDenoiser,
    xyz: Tensor | np.ndarray,  # [N, 3] world coordinates of the whole cloud
    local_cond: Tensor | np.ndarray,  # [N, C] per-point condition (same layout as in training)
    global_feats: Optional[Tensor],  # [32, D, 5, 5] lattice prior features, or None (A1)
    *,
    num_steps: int = 50,
    seed: int = 0,
    frame: Optional[SphereFrame] = None,
    write_chunk: Optional[int] = 32768,
    guidance_scale: float = 1.0,
    num_train_timesteps: int = 1000,
    device: Optional[torch.device] = None,
    patch_points: Optional[int] = None,
    patch_coverage: float = 2.0,
    patch_batch: Optional[int] = 64,
) -> Tensor:
    """DDIM-samples PBR features for the ENTIRE cloud at once (paper: N_test = N, no view-dropout).

    Use the EMA weights (``load_stage2_checkpoint`` returns them). ``write_chunk`` bounds the
    memory of the point-side attention/MLP; the Read attention is O(N) memory (SDPA).

    Args:
        frame: unit-sphere frame; None fits it on ``xyz`` (what Stage I inference has).
        device: where the DDIM loop runs (the frame and the noise are made on the CPU first, so
            a device changes no draw); None = the CPU, as before. The result is on ``device``.
        patch_points: None = the whole cloud at once (the paper); else overlapping k-NN patches
            of that many points, ``patch_coverage`` patches per point on average, sampled
            ``patch_batch`` at a time and blended (``gspi.stage2.patches``, issue 52).
    Returns:
        [N, 5] float32 in [0, 1]: albedo (sRGB-encoded) RGB, roughness, metallic.
    """
    xyz = torch.as_tensor(np.asarray(xyz), dtype=torch.float64)
    frame = fit_unit_sphere(xyz) if frame is None else frame
    xyz_unit = to_unit_sphere(xyz, frame).float()[None]
    tokens = None
    if global_feats is not None and global_feats.shape[1] > 0:
        tokens = global_feats.float().flatten(2).transpose(1, 2)[None]  # [1, 32, 25, D]
    inputs = Stage2Inputs(xyz=xyz_unit, local_cond=torch.as_tensor(np.asarray(local_cond)).float()[None],
                          global_tokens=tokens)
    if device is not None:
        inputs = inputs.to(device)
    generator = torch.Generator().manual_seed(int(seed))
    alphas = cosine_alphas_cumprod(num_train_timesteps)
    if patch_points is None:
        f = ddim_sample(model.eval(), inputs, num_steps, generator, guidance_scale=guidance_scale,
                        write_chunk=write_chunk, alphas_cumprod=alphas)
        return pbr_from_model(f[0])
    patches, centres = cover_patches(xyz.numpy(), int(patch_points), coverage=patch_coverage, seed=int(seed))
    values = []
    for sl in patch_batches(patches, patch_batch):
        idx = torch.from_numpy(patches[sl]).to(inputs.xyz.device)
        b = len(idx)
        part = Stage2Inputs(xyz=inputs.xyz[0][idx], local_cond=inputs.local_cond[0][idx],
                            global_tokens=None if inputs.global_tokens is None
                            else inputs.global_tokens.expand(b, *inputs.global_tokens.shape[1:]))
        f = ddim_sample(model.eval(), part, num_steps, generator, guidance_scale=guidance_scale,
                        write_chunk=write_chunk, alphas_cumprod=alphas)
        values.append(pbr_from_model(f).cpu())
    pbr = blend_patches(torch.cat(values), patches, blend_weights(xyz.numpy(), patches, centres), len(xyz))
    return pbr if device is None else pbr.to(device)


def mean_point_pbr(model: RCWDenoiser, xyz, local_cond, global_feats: Optional[Tensor], *,
                   num_samples: int = 1, seed: int = 0, **kwargs) -> np.ndarray:
    """[N, 5] float32 numpy: the mean of ``num_samples`` (at least 1) ``predict_point_pbr``
    samples with noise seeds ``seed, seed + 1, ...`` (``stage2.inference.num_samples``; the
    paper draws one). ``kwargs`` go to ``predict_point_pbr``. gspi-run's inference and Table 2's
    measure both average here."""
    samples = [predict_point_pbr(model, xyz, local_cond, global_feats, seed=seed + k, **kwargs).cpu().numpy()
               for k in range(max(1, int(num_samples)))]
    return np.mean(samples, axis=0).astype(np.float32)
