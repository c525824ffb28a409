"""Stage II denoiser: the PointInfinity two-stream Read-Compute-Write transformer adapted to
GS-PI (paper Sec. "Conditional Point Cloud Diffusion Transformer"; method-notes 1.1).

Point stream (one token per point, no positional embedding, so the network is
permutation-equivariant over points and accepts any N):
    x = LN(Linear([fourier(xyz) | local_cond | f_t]))                    # [B, N, point_dim]
Latent stream (method-notes 1.1: conditioning and time enter as tokens, not AdaLN):
    z = [learned latents (num_latents) | global prior tokens (25 V) | time token]
    global token (v, c) = Linear(LN(feature)) + view_embed[view_ids[v]] + cell_embed[c]
    time token = MLP(sinusoid(t))
    z += LN_zero(p + MLP(p)),  p = stopgrad(previous latent stream)   (latent self-conditioning)
then ``num_blocks`` RCW blocks and ``eps_hat = Linear(LN(x))`` [B, N, 5].

The head's output is eps (the paper), x0 (read as eps at t), or ``x0_readout`` (issue 66; not
the paper): x0 as a correction to the light read-out's material carried in the local condition,
``x0 = pbr_to_model(read-out) + Linear(LN(x))``, with that last layer zero at init, so an
untrained model samples the read-out itself and training learns only where to depart from it.
The offset is read from the condition before the classifier-free drop (the read-out is the
starting point, not a condition to guide). With ``readout_metal_gate`` the head adds no metal
where the read-out rules it out (its metallic exactly 0: every point of a scene that fails the
read-out's scene-level metal test, ``stage2.data.light_metal_min_evidence``), so the prior cannot
undo that test.

Classifier-free guidance: ``cond_keep`` [B] multiplies the local condition and the global
tokens by 0 for dropped samples (PointInfinity: the null condition is the learned embedding
of zeros). Geometry (xyz) is never dropped: it is the frozen prior, not a condition to guide.
Randomness (which samples drop) is drawn by the caller, so ``forward`` is deterministic.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Optional

import torch
from torch import Tensor, nn

from gspi.stage2.blocks import Mlp, RCWBlock, fourier_dim, fourier_features, timestep_sinusoid
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.light_condition import READOUT_PBR_COLUMNS
from gspi.stage2.normalize import pbr_to_model
from gspi.stage2.schedule import cosine_alphas_cumprod, eps_from_f0

PREDICTIONS = ("eps", "x0", "x0_readout")  # what the output head predicts (RCWDenoiser.forward)
READOUT_MATERIAL = len(READOUT_PBR_COLUMNS)
METALLIC = 4  # the metallic channel of the diffused features (albedo RGB, roughness, metallic)
VIEW_ONEHOT_DIM = 32  # V = 32 lattice views (paper Sec. "Learned View-Direction Conditioning")


@dataclass(frozen=True, kw_only=True)
class RCWConfig:
    """Sizes and switches of :class:`RCWDenoiser`. Defaults: PointInfinity's denoiser.

    Ablations change one field: A1 (no global prior) ``global_token_dim=0``; A2 (no view
    one-hot) ``use_view_onehot=False, local_cond_dim=3``; A5 (direct multi-view injection,
    32 views x (RGB + visibility)) ``use_view_onehot=False, local_cond_dim=128``.
    """

    num_latents: int = 256  # N_lat learned latent tokens
    latent_dim: int = 768  # width of the latent stream
    point_dim: int = 512  # width of the point stream
    num_blocks: int = 6  # RCW blocks
    num_compute_layers: int = 4  # latent self-attention layers per block
    num_heads: int = 8  # attention heads (divides latent_dim and point_dim)
    mlp_ratio: float = 4.0  # MLP hidden width / token width
    fourier_bands: int = 8  # octaves of the xyz positional encoding (0 = raw xyz)
    feature_dim: int = 5  # diffused channels: albedo RGB, roughness, metallic
    local_cond_dim: int = 35  # per-point condition width: Top-RGB 3 + view one-hot 32
    use_view_onehot: bool = True  # local_cond ends with the 32-dim view-source one-hot (A2: False)
    global_token_dim: int = 768  # encoder feature width of the global prior (0 = none, A1)
    global_grid_cells: int = 25  # 5 x 5 pooled encoder cells per view
    num_lattice_views: int = 32  # size of the per-view positional embedding table
    self_condition: bool = True  # latent self-conditioning input
    point_global_skip: bool = False  # also add LN(mean of the global tokens) to every point token (a per-point MLP that sees the pooled prior)
    cond_drop_prob: float = 0.1  # training probability of the null condition (CFG)
    prediction: str = "eps"  # what the output head predicts: "eps" (paper), "x0" or "x0_readout" (see forward)
    readout_column: Optional[int] = None  # x0_readout: where the light read-out's columns start in local_cond
    readout_metal_gate: bool = False  # x0_readout: no metallic correction where the read-out's metallic is 0
    num_train_timesteps: int = 1000  # cosine schedule length (the x0 -> eps conversion uses it)

    def __post_init__(self) -> None:
        for name in ("latent_dim", "point_dim"):
            if getattr(self, name) % self.num_heads:
                raise ValueError(f"{name}={getattr(self, name)} is not divisible by num_heads={self.num_heads}")
        if self.use_view_onehot and self.local_cond_dim < VIEW_ONEHOT_DIM:
            raise ValueError(f"use_view_onehot needs local_cond_dim >= {VIEW_ONEHOT_DIM}, "
                             f"got {self.local_cond_dim}")
        if self.prediction not in PREDICTIONS:
            raise ValueError(f"prediction must be one of {PREDICTIONS}, got {self.prediction!r}")
        if (self.prediction == "x0_readout") != (self.readout_column is not None):
            raise ValueError("prediction 'x0_readout' and readout_column go together (the column where the light "
                             f"read-out starts in the local condition), got {self.prediction!r} and {self.readout_column}")
        if self.readout_metal_gate and self.prediction != "x0_readout":
            raise ValueError("readout_metal_gate gates the x0_readout head's metallic correction; it needs "
                             f"prediction 'x0_readout', got {self.prediction!r}")
        if self.readout_column is not None and not 0 <= self.readout_column <= self.local_cond_dim - READOUT_MATERIAL:
            raise ValueError(f"readout_column={self.readout_column} leaves no {READOUT_MATERIAL} read-out columns in a "
                             f"{self.local_cond_dim}-dim local condition")
        if not 0.0 <= self.cond_drop_prob < 1.0:
            raise ValueError(f"cond_drop_prob must be in [0, 1), got {self.cond_drop_prob}")

    @property
    def point_input_dim(self) -> int:
        """Width of the point-token input: Fourier xyz + local condition + noisy features."""
        return fourier_dim(self.fourier_bands) + self.local_cond_dim + self.feature_dim

    def num_latent_tokens(self, num_views: int) -> int:
        """Length of the latent stream for ``num_views`` global-prior views."""
        return self.num_latents + self.global_grid_cells * num_views + 1


class DenoiserOutput(NamedTuple):
    eps: Tensor  # [B, N, feature_dim] predicted noise
    latents: Tensor  # [B, L, latent_dim] final latent stream, the next call's prev_latents


class RCWDenoiser(nn.Module):
    """Eps-prediction network ``eps_theta(f_t, t | xyz, local_cond, global prior)``."""

    def __init__(self, config: RCWConfig):
        super().__init__()
        self.config = c = config
        self.point_embed = nn.Linear(c.point_input_dim, c.point_dim)
        self.point_norm = nn.LayerNorm(c.point_dim)
        self.latents = nn.Parameter(torch.empty(c.num_latents, c.latent_dim))
        if c.global_token_dim > 0:
            self.global_norm = nn.LayerNorm(c.global_token_dim)
            self.global_proj = nn.Linear(c.global_token_dim, c.latent_dim)
            self.view_embed = nn.Parameter(torch.empty(c.num_lattice_views, c.latent_dim))
            self.cell_embed = nn.Parameter(torch.empty(c.global_grid_cells, c.latent_dim))
        if c.point_global_skip and c.global_token_dim > 0:  # docs/log/stage2.md "Where the signal is lost"
            self.point_global_norm = nn.LayerNorm(c.global_token_dim)
            self.point_global_proj = nn.Linear(c.global_token_dim, c.point_dim)
        hidden = int(c.latent_dim * c.mlp_ratio)
        self.time_mlp = Mlp(in_dim=c.latent_dim, hidden_dim=hidden)
        if c.self_condition:
            self.self_cond_mlp = Mlp(in_dim=c.latent_dim, hidden_dim=hidden)
            self.self_cond_norm = nn.LayerNorm(c.latent_dim)
        self.blocks = nn.ModuleList(
            RCWBlock(latent_dim=c.latent_dim, point_dim=c.point_dim, num_compute_layers=c.num_compute_layers,
                     num_heads=c.num_heads, mlp_ratio=c.mlp_ratio)
            for _ in range(c.num_blocks))
        self.out_norm = nn.LayerNorm(c.point_dim)
        self.out = nn.Linear(c.point_dim, c.feature_dim)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """PointInfinity init: xavier-uniform Linear weights, zero biases, unit LayerNorms,
        N(0, 0.02) tokens, and a ZERO self-conditioning LayerNorm (a no-op at init)."""
        for m in self.modules():
            if isinstance(m, nn.Linear):
                nn.init.xavier_uniform_(m.weight)
                nn.init.zeros_(m.bias)
            elif isinstance(m, nn.LayerNorm):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for p in (self.latents, getattr(self, "view_embed", None), getattr(self, "cell_embed", None)):
            if p is not None:
                nn.init.normal_(p, std=0.02)
        if self.config.self_condition:
            nn.init.zeros_(self.self_cond_norm.weight)
            nn.init.zeros_(self.self_cond_norm.bias)
        if self.config.prediction == "x0_readout":  # the untrained model is the read-out
            nn.init.zeros_(self.out.weight)

    def forward(
        self,
        f_t: Tensor,  # [B, N, 5] noisy features
        t: Tensor | int,  # [B] or scalar integer timesteps
        inputs: Stage2Inputs,
        *,
        prev_latents: Optional[Tensor] = None,  # [B, L, latent_dim] previous call's latents
        cond_keep: Optional[Tensor] = None,  # [B] bool/float, 0 = null condition; None = all kept
        write_chunk: Optional[int] = None,  # points per Write chunk (inference memory bound)
    ) -> DenoiserOutput:
        """Predicts the feature noise.

        Returns:
            DenoiserOutput(eps [B, N, 5], latents [B, L, latent_dim]),
            L = num_latents + 25 V + 1.
        """
        t = torch.as_tensor(t, device=f_t.device).expand(inputs.xyz.shape[0])
        head, latents = self.head(f_t, t, inputs, prev_latents=prev_latents, cond_keep=cond_keep,
                                  write_chunk=write_chunk)
        if self.config.prediction == "eps":
            return DenoiserOutput(eps=head, latents=latents)
        return DenoiserOutput(eps=self.eps_from_x0(self.x0_of_head(head, inputs), f_t, t), latents=latents)

    def x0_of_head(self, head: Tensor, inputs: Stage2Inputs) -> Tensor:
        """[B, N, 5] the clean-feature estimate of an x0 head's output: itself, or with
        ``x0_readout`` the light read-out's material (diffusion space) plus it."""
        if self.config.prediction != "x0_readout":
            return head
        c = int(self.config.readout_column)
        columns = [c + k for k in READOUT_PBR_COLUMNS]
        readout = inputs.local_cond[..., columns].to(head.dtype).clamp(0.0, 1.0)
        if self.config.readout_metal_gate:  # no metal added where the read-out rules it out
            head = torch.cat([head[..., :METALLIC], head[..., METALLIC:] * (readout[..., METALLIC:] > 0)], dim=-1)
        return pbr_to_model(readout) + head

    def head(self, f_t: Tensor, t: Tensor, inputs: Stage2Inputs, *, prev_latents: Optional[Tensor] = None,
             cond_keep: Optional[Tensor] = None, write_chunk: Optional[int] = None) -> tuple[Tensor, Tensor]:
        """(raw head output [B, N, 5], final latents): eps or x0 as ``config.prediction`` says.
        A direct (one-pass) regressor built on this backbone reads it as x0."""
        b, n = inputs.xyz.shape[:2]
        if f_t.shape != (b, n, self.config.feature_dim):
            raise ValueError(f"f_t must be [B, N, {self.config.feature_dim}] = {(b, n)}, got {tuple(f_t.shape)}")
        keep = None if cond_keep is None else cond_keep.to(f_t.dtype).reshape(b, 1, 1)
        points = self.embed_points(f_t, inputs, keep)
        latents = torch.cat([self.latents.expand(b, -1, -1), *self.embed_global(inputs, keep),
                             self.embed_time(t)], dim=1)
        latents = self.add_self_condition(latents, prev_latents)
        for block in self.blocks:
            latents, points = block(latents, points, write_chunk=write_chunk)
        return self.out(self.out_norm(points)), latents

    def eps_from_x0(self, f0_hat: Tensor, f_t: Tensor, t: Tensor) -> Tensor:
        """An x0-predicting head read as eps (:func:`~gspi.stage2.schedule.eps_from_f0` at ``t``).

        The loss (Min-SNR-gamma eps MSE) and the DDIM sampler are unchanged; only what the
        network has to represent changes. With an eps head, the clean-feature estimate at
        high noise is ``(f_t - sqrt(1 - abar) eps_hat) / sqrt(abar)``, a tiny correction to an
        identity map that a small network reproduces poorly, so its conditions hardly matter
        (docs/STAGE2.md "Why an x0 head for the CPU checkpoints").
        """
        abar = self._alphas_cumprod(f_t.device)[t.long()].to(f_t.dtype).reshape(-1, 1, 1)
        return eps_from_f0(f_t, f0_hat, abar)

    def _alphas_cumprod(self, device: torch.device) -> Tensor:
        cached = getattr(self, "_abar", None)
        if cached is None or cached.device != device:
            cached = cosine_alphas_cumprod(self.config.num_train_timesteps).to(device)
            self._abar = cached
        return cached

    def embed_points(self, f_t: Tensor, inputs: Stage2Inputs, keep: Optional[Tensor]) -> Tensor:
        """[B, N, point_dim] point tokens from Fourier xyz, local condition and noisy features."""
        local = inputs.local_cond.to(f_t.dtype)
        if local.shape[-1] != self.config.local_cond_dim:
            raise ValueError(f"local_cond has {local.shape[-1]} channels, config.local_cond_dim = "
                             f"{self.config.local_cond_dim}")
        if keep is not None:
            local = local * keep
        tokens = torch.cat([fourier_features(inputs.xyz.to(f_t.dtype), self.config.fourier_bands), local, f_t], -1)
        points = self.point_norm(self.point_embed(tokens))
        if hasattr(self, "point_global_proj") and inputs.global_tokens is not None and inputs.global_tokens.shape[1]:
            pooled = inputs.global_tokens.to(f_t.dtype).mean(dim=(1, 2))  # [B, D]: the scene's pooled prior
            if keep is not None:
                pooled = pooled * keep[:, 0]
            points = points + self.point_global_proj(self.point_global_norm(pooled))[:, None]
        return points

    def embed_global(self, inputs: Stage2Inputs, keep: Optional[Tensor]) -> list[Tensor]:
        """[[B, 25 V, latent_dim]] projected global-prior tokens with view/cell embeddings
        (an empty list for V = 0 or no prior)."""
        tokens = inputs.global_tokens
        if tokens is None or tokens.shape[1] == 0:
            return []
        c = self.config
        if c.global_token_dim == 0:
            raise ValueError("global_tokens given, but the model has no global prior (global_token_dim=0)")
        b, v, cells, d = tokens.shape
        if (cells, d) != (c.global_grid_cells, c.global_token_dim):
            raise ValueError(f"global_tokens must be [B, V, {c.global_grid_cells}, {c.global_token_dim}], "
                             f"got {tuple(tokens.shape)}")
        tokens = tokens.to(self.latents.dtype)
        if keep is not None:  # null condition: LN(0) = LN bias, i.e. a learned embedding of zeros
            tokens = tokens * keep[..., None]
        tokens = self.global_proj(self.global_norm(tokens))
        view_ids = inputs.resolved_view_ids()
        tokens = tokens + self.view_embed[view_ids][:, :, None] + self.cell_embed
        return [tokens.flatten(1, 2)]

    def embed_time(self, t: Tensor) -> Tensor:
        """[B] timesteps -> [B, 1, latent_dim] time token ``MLP(sinusoid(t))``."""
        emb = timestep_sinusoid(t, self.config.latent_dim).to(self.latents.dtype)
        return self.time_mlp(emb)[:, None]

    def add_self_condition(self, latents: Tensor, prev_latents: Optional[Tensor]) -> Tensor:
        """``z + LN_zero(p + MLP(p))`` with p = stopgrad(prev_latents) (zeros when None)."""
        if not self.config.self_condition:
            if prev_latents is not None:
                raise ValueError("prev_latents given, but config.self_condition is False")
            return latents
        if prev_latents is None:
            prev = torch.zeros_like(latents)
        elif prev_latents.shape != latents.shape:
            raise ValueError(f"prev_latents {tuple(prev_latents.shape)} must match the latent stream "
                             f"{tuple(latents.shape)}")
        else:
            prev = prev_latents.detach()
        return latents + self.self_cond_norm(prev + self.self_cond_mlp(prev))


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
