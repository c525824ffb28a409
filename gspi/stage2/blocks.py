"""Building blocks of the PointInfinity two-stream Read-Compute-Write (RCW) transformer
(Huang et al. 2024, facebookresearch/PointInfinity ``modules.py``; method-notes 1.1).

Pre-LayerNorm residual blocks with ordinary softmax multi-head attention
(``scaled_dot_product_attention``), bias-ful projections and a Linear-GELU-Linear MLP.
There is no self-attention among points, so every block is O(N) in the number of points.
"""
from __future__ import annotations

import math
from typing import Optional

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class Mlp(nn.Module):
    """Linear -> GELU -> Linear (timm ``Mlp``)."""

    def __init__(self, *, in_dim: int, hidden_dim: int, out_dim: Optional[int] = None):
        super().__init__()
        self.fc1 = nn.Linear(in_dim, hidden_dim)
        self.fc2 = nn.Linear(hidden_dim, out_dim or in_dim)

    def forward(self, x: Tensor) -> Tensor:
        return self.fc2(F.gelu(self.fc1(x)))


class Attention(nn.Module):
    """Multi-head attention whose queries (width ``query_dim``) attend to a context of width
    ``context_dim``; keys/values are projected to ``query_dim``. Self-attention when the
    context is the query sequence itself."""

    def __init__(self, *, query_dim: int, context_dim: int, num_heads: int):
        super().__init__()
        if query_dim % num_heads:
            raise ValueError(f"query_dim {query_dim} is not divisible by num_heads {num_heads}")
        self.num_heads = num_heads
        self.to_q = nn.Linear(query_dim, query_dim)
        self.to_kv = nn.Linear(context_dim, 2 * query_dim)
        self.proj = nn.Linear(query_dim, query_dim)

    def split_heads(self, x: Tensor) -> Tensor:
        """[B, L, H * d] -> [B, H, L, d]."""
        b, n, _ = x.shape
        return x.view(b, n, self.num_heads, -1).transpose(1, 2)

    def keys_values(self, context: Tensor) -> tuple[Tensor, Tensor]:
        """[B, M, context_dim] -> keys, values [B, H, M, d] (computed once per chunked write)."""
        k, v = self.to_kv(context).chunk(2, dim=-1)
        return self.split_heads(k), self.split_heads(v)

    def forward(self, query: Tensor, keys: Tensor, values: Tensor) -> Tensor:
        """query [B, L, query_dim], keys/values [B, H, M, d] -> [B, L, query_dim]."""
        out = F.scaled_dot_product_attention(self.split_heads(self.to_q(query)), keys, values)
        b, _, n, _ = out.shape
        return self.proj(out.transpose(1, 2).reshape(b, n, -1))


class CrossAttentionBlock(nn.Module):
    """``x <- x + Attn(LN(x), LN(ctx)); x <- x + MLP(LN(x))`` (PointInfinity's cross block).

    ``chunk_size`` splits the queries: each query row is independent, so the result equals the
    unchunked one while the attention and MLP activations stay O(chunk_size).
    """

    def __init__(self, *, query_dim: int, context_dim: int, num_heads: int, mlp_ratio: float):
        super().__init__()
        self.norm_query = nn.LayerNorm(query_dim)
        self.norm_context = nn.LayerNorm(context_dim)
        self.attn = Attention(query_dim=query_dim, context_dim=context_dim, num_heads=num_heads)
        self.norm_mlp = nn.LayerNorm(query_dim)
        self.mlp = Mlp(in_dim=query_dim, hidden_dim=int(query_dim * mlp_ratio))

    def forward(
        self,
        x: Tensor,  # [B, L, query_dim]
        context: Tensor,  # [B, M, context_dim]
        *,
        chunk_size: Optional[int] = None,
    ) -> Tensor:
        keys, values = self.attn.keys_values(self.norm_context(context))
        if chunk_size is None or chunk_size >= x.shape[1]:
            return self._update(x, keys, values)
        return torch.cat([self._update(xc, keys, values) for xc in x.split(chunk_size, dim=1)], dim=1)

    def _update(self, x: Tensor, keys: Tensor, values: Tensor) -> Tensor:
        x = x + self.attn(self.norm_query(x), keys, values)
        return x + self.mlp(self.norm_mlp(x))


class SelfAttentionBlock(nn.Module):
    """Pre-LN transformer layer on one sequence: ``z <- z + Attn(LN(z)); z <- z + MLP(LN(z))``."""

    def __init__(self, *, dim: int, num_heads: int, mlp_ratio: float):
        super().__init__()
        self.norm_attn = nn.LayerNorm(dim)
        self.attn = Attention(query_dim=dim, context_dim=dim, num_heads=num_heads)
        self.norm_mlp = nn.LayerNorm(dim)
        self.mlp = Mlp(in_dim=dim, hidden_dim=int(dim * mlp_ratio))

    def forward(self, x: Tensor) -> Tensor:  # [B, L, dim] -> [B, L, dim]
        h = self.norm_attn(x)
        x = x + self.attn(h, *self.attn.keys_values(h))
        return x + self.mlp(self.norm_mlp(x))


class RCWBlock(nn.Module):
    """One Read-Compute-Write block (method-notes 1.1).

    Read: latents attend to all N point tokens (+ MLP). Compute: ``num_compute_layers``
    self-attention layers on the latents. Write: point tokens attend to the latents (+ MLP),
    optionally in chunks of ``write_chunk`` points.
    """

    def __init__(self, *, latent_dim: int, point_dim: int, num_compute_layers: int,
                 num_heads: int, mlp_ratio: float):
        super().__init__()
        self.read = CrossAttentionBlock(query_dim=latent_dim, context_dim=point_dim,
                                        num_heads=num_heads, mlp_ratio=mlp_ratio)
        self.compute = nn.ModuleList(
            SelfAttentionBlock(dim=latent_dim, num_heads=num_heads, mlp_ratio=mlp_ratio)
            for _ in range(num_compute_layers))
        self.write = CrossAttentionBlock(query_dim=point_dim, context_dim=latent_dim,
                                         num_heads=num_heads, mlp_ratio=mlp_ratio)

    def forward(
        self,
        latents: Tensor,  # [B, L, latent_dim]
        points: Tensor,  # [B, N, point_dim]
        *,
        write_chunk: Optional[int] = None,
    ) -> tuple[Tensor, Tensor]:
        latents = self.read(latents, points)
        for layer in self.compute:
            latents = layer(latents)
        points = self.write(points, latents, chunk_size=write_chunk)
        return latents, points


def timestep_sinusoid(t: Tensor, dim: int, *, max_period: float = 10000.0) -> Tensor:
    """Sinusoidal embedding of raw timestep values, cos first (Point-E / PointInfinity).

    Args:
        t: [B] timesteps (integer indices, any float dtype allowed).
        dim: embedding width (even).
    Returns:
        [B, dim] float32 ``[cos(t * f_i), sin(t * f_i)]``, ``f_i = exp(-ln(max_period) i / (dim/2))``.
    """
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    args = t.float()[:, None] * freqs[None]
    emb = torch.cat([torch.cos(args), torch.sin(args)], dim=-1)
    return F.pad(emb, (0, dim % 2))


def fourier_features(xyz: Tensor, num_bands: int) -> Tensor:
    """NeRF-style positional encoding of unit-sphere coordinates.

    Args:
        xyz: [B, N, 3] coordinates in [-1, 1].
        num_bands: L octaves, frequencies ``2^k * pi``, k = 0..L-1.
    Returns:
        [B, N, 3 + 6 L] ``[xyz, sin(2^k pi xyz), cos(2^k pi xyz)]``.
    """
    if num_bands == 0:
        return xyz
    freqs = math.pi * 2.0 ** torch.arange(num_bands, device=xyz.device, dtype=xyz.dtype)
    args = (xyz[..., None, :] * freqs[:, None]).flatten(-2)  # [B, N, 3 L]
    return torch.cat([xyz, torch.sin(args), torch.cos(args)], dim=-1)


def fourier_dim(num_bands: int) -> int:
    """Width of :func:`fourier_features` for ``num_bands`` octaves."""
    return 3 + 6 * num_bands
