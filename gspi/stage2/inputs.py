"""The conditioning inputs of the Stage II denoiser (paper Sec. "Multi-Scale Cross-View
Conditioning Mechanism"), as one batch."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import torch
from torch import Tensor


@dataclass
class Stage2Inputs:
    """Everything the denoiser sees besides the noisy features and the timestep.

    All samples of a batch share N (training draws fixed-size subsets, inference runs one
    scene at a time) and V.

    Attributes:
        xyz: [B, N, 3] frozen point coordinates, normalised to the unit sphere
            (``gspi.stage2.normalize.to_unit_sphere``).
        local_cond: [B, N, C] per-point condition: Top-RGB 3 + view-source one-hot 32
            (C = 35, default); Top-RGB only (C = 3, ablation A2); 32 views x (RGB + visibility)
            (C = 128, ablation A5).
        global_tokens: [B, V, 25, D] global semantic prior, a 5x5 grid of frozen encoder
            (DINOv2) features per view, or None (no prior, ablation A1; same as V = 0).
        view_ids: [B, V] int64 lattice indices (0..31) of the views in ``global_tokens``, for
            the per-view positional embedding; None means ``arange(V)`` for every sample.
    """

    xyz: Tensor
    local_cond: Tensor
    global_tokens: Optional[Tensor] = None
    view_ids: Optional[Tensor] = None

    def __post_init__(self) -> None:
        if self.xyz.dim() != 3 or self.xyz.shape[-1] != 3:
            raise ValueError(f"xyz must be [B, N, 3], got {tuple(self.xyz.shape)}")
        if self.local_cond.shape[:2] != self.xyz.shape[:2]:
            raise ValueError(f"local_cond {tuple(self.local_cond.shape)} must be [B, N, C] "
                             f"with B, N of xyz {tuple(self.xyz.shape)}")
        if self.global_tokens is not None:
            b, v = self.global_tokens.shape[:2]
            if self.global_tokens.dim() != 4 or b != self.xyz.shape[0]:
                raise ValueError(f"global_tokens must be [B, V, cells, D], got "
                                 f"{tuple(self.global_tokens.shape)}")
            if self.view_ids is not None and tuple(self.view_ids.shape) != (b, v):
                raise ValueError(f"view_ids must be [B, V] = {(b, v)}, got {tuple(self.view_ids.shape)}")

    @property
    def batch_size(self) -> int:
        return self.xyz.shape[0]

    @property
    def num_points(self) -> int:
        return self.xyz.shape[1]

    @property
    def num_views(self) -> int:
        return 0 if self.global_tokens is None else self.global_tokens.shape[1]

    def resolved_view_ids(self) -> Optional[Tensor]:
        """[B, V] int64 view ids (``arange(V)`` when not given), None without global tokens."""
        if self.global_tokens is None:
            return None
        if self.view_ids is not None:
            return self.view_ids.long()
        ids = torch.arange(self.num_views, device=self.global_tokens.device)
        return ids.expand(self.batch_size, -1)

    def to(self, device: torch.device | str) -> "Stage2Inputs":
        def move(x: Optional[Tensor]) -> Optional[Tensor]:
            return None if x is None else x.to(device)
        return replace(self, xyz=move(self.xyz), local_cond=move(self.local_cond),
                       global_tokens=move(self.global_tokens), view_ids=move(self.view_ids))

    def select_views(self, view_index: Tensor) -> "Stage2Inputs":
        """Keeps views ``view_index`` [B, V'] (indices into dim 1) of the global prior.

        Used for view-dropout (training: 16 of 32 views per sample).
        """
        if self.global_tokens is None:
            return self
        b = torch.arange(self.batch_size, device=view_index.device)[:, None]
        ids = self.resolved_view_ids()
        return replace(self, global_tokens=self.global_tokens[b, view_index],
                       view_ids=ids[b, view_index])
