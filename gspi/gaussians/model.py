"""Container of 2D Gaussian surfels (2DGS) with optional PBR attributes.

A plain dataclass of raw (pre-activation) tensors rather than an ``nn.Module``:
it is the data passed between stages and written to PLY, it is sliced and
re-assembled freely (``subset``), and each stage optimises a different subset
of its fields (Stage III: PBR logits, opacities and scales only), so callers
``requires_grad_`` the fields they train and hand them to their optimizer.
Activations follow hbb1/2d-gaussian-splatting: scale = exp, opacity = sigmoid,
rotation = normalised quaternion (w, x, y, z); the PBR logits use sigmoid.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Optional

import torch
from torch import Tensor

from gspi.gaussians.projection import quat_to_rotmat
from gspi.gaussians.sh import num_sh_bases, sh_colors, sh_degree_from_bases, sh_to_rgb

PBR_FIELDS = ("albedo_logits", "roughness_logits", "metallic_logits")


@dataclass
class Gaussians2D:
    """N 2D Gaussian surfels, raw parameters (paper: G = {mu_i, q_i, s_i, alpha_i}).

    Attributes:
        means: [N, 3] world-space centres.
        quats: [N, 4] rotations (w, x, y, z), not necessarily normalised.
        log_scales: [N, 2] log of the two tangent scales (world units).
        opacity_logits: [N] inverse-sigmoid opacities.
        sh_dc: [N, 1, 3] SH DC coefficients.
        sh_rest: [N, K - 1, 3] higher SH coefficients, K = (degree + 1) ** 2.
        albedo_logits: optional [N, 3] inverse-sigmoid albedo (LINEAR RGB; renderers composite
            it linearly and sRGB-encode the map, as Stage III and its exports do).
        roughness_logits: optional [N, 1] inverse-sigmoid roughness.
        metallic_logits: optional [N, 1] inverse-sigmoid metallic.
    """

    means: Tensor
    quats: Tensor
    log_scales: Tensor
    opacity_logits: Tensor
    sh_dc: Tensor
    sh_rest: Tensor
    albedo_logits: Optional[Tensor] = None
    roughness_logits: Optional[Tensor] = None
    metallic_logits: Optional[Tensor] = None

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {
            "means": (n, 3), "quats": (n, 4), "log_scales": (n, 2), "opacity_logits": (n,),
            "sh_dc": (n, 1, 3), "albedo_logits": (n, 3), "roughness_logits": (n, 1), "metallic_logits": (n, 1),
        }
        for name, shape in expected.items():
            value = getattr(self, name)
            if value is not None and tuple(value.shape) != shape:
                raise ValueError(f"Gaussians2D.{name} must have shape {shape}, got {tuple(value.shape)}")
        if self.sh_rest.dim() != 3 or self.sh_rest.shape[0] != n or self.sh_rest.shape[2] != 3:
            raise ValueError(f"Gaussians2D.sh_rest must be [N, K-1, 3], got {tuple(self.sh_rest.shape)}")
        sh_degree_from_bases(self.sh_rest.shape[1] + 1)  # raises for a non-square count
        present = [getattr(self, name) is not None for name in PBR_FIELDS]
        if any(present) and not all(present):
            raise ValueError(f"PBR fields {PBR_FIELDS} must be all set or all None")

    @classmethod
    def empty(
        cls, num: int, sh_degree: int = 3, *, pbr: bool = False, dtype=torch.float32, device=None
    ) -> "Gaussians2D":
        """Zero-initialised surfels (identity rotation, unit scale, opacity 0.5, grey)."""
        kw = dict(dtype=dtype, device=device)
        quats = torch.zeros(num, 4, **kw)
        quats[:, 0] = 1.0
        extra = {}
        if pbr:
            extra = {"albedo_logits": torch.zeros(num, 3, **kw), "roughness_logits": torch.zeros(num, 1, **kw),
                     "metallic_logits": torch.zeros(num, 1, **kw)}
        return cls(torch.zeros(num, 3, **kw), quats, torch.zeros(num, 2, **kw), torch.zeros(num, **kw),
                   torch.zeros(num, 1, 3, **kw), torch.zeros(num, num_sh_bases(sh_degree) - 1, 3, **kw), **extra)

    # ---- sizes -------------------------------------------------------------------
    @property
    def num_gaussians(self) -> int:
        """Number of surfels N."""
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        """SH degree stored (0..3), from the number of coefficients."""
        return sh_degree_from_bases(self.sh_rest.shape[1] + 1)

    @property
    def has_pbr(self) -> bool:
        """True when albedo / roughness / metallic logits are present."""
        return self.albedo_logits is not None

    # ---- activated values --------------------------------------------------------
    @property
    def scales(self) -> Tensor:
        """[N, 2] tangent scales, exp(log_scales)."""
        return torch.exp(self.log_scales)

    @property
    def opacities(self) -> Tensor:
        """[N] opacities in (0, 1)."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def rotations(self) -> Tensor:
        """[N, 4] unit quaternions (w, x, y, z)."""
        return torch.nn.functional.normalize(self.quats, dim=-1)

    @property
    def normals(self) -> Tensor:
        """[N, 3] world-space surfel normals (rotation column 2; not camera-facing)."""
        return quat_to_rotmat(self.quats)[..., 2]

    @property
    def sh(self) -> Tensor:
        """[N, K, 3] all SH coefficients (DC first), gsplat's layout."""
        return torch.cat([self.sh_dc, self.sh_rest], dim=1)

    @property
    def albedo(self) -> Tensor:
        """[N, 3] albedo in [0, 1]."""
        return torch.sigmoid(self._pbr("albedo_logits"))

    @property
    def roughness(self) -> Tensor:
        """[N, 1] roughness in [0, 1]."""
        return torch.sigmoid(self._pbr("roughness_logits"))

    @property
    def metallic(self) -> Tensor:
        """[N, 1] metallic in [0, 1]."""
        return torch.sigmoid(self._pbr("metallic_logits"))

    def _pbr(self, name: str) -> Tensor:
        value = getattr(self, name)
        if value is None:
            raise ValueError(f"these Gaussians carry no PBR attributes ({name} is None)")
        return value

    def pbr_features(self) -> Tensor:
        """[N, 5] activated (albedo RGB, roughness, metallic), the paper's f_i."""
        return torch.cat([self.albedo, self.roughness, self.metallic], dim=-1)

    def base_color(self) -> Tensor:
        """[N, 3] view-independent colour from the SH DC term, ``0.5 + C0 * f_dc``."""
        return sh_to_rgb(self.sh_dc[:, 0, :])

    def colors(self, camera_center: Tensor, degree: Optional[int] = None) -> Tensor:
        """[N, 3] view-dependent colour ``max(SH(dir) + 0.5, 0)`` seen from ``camera_center`` [3]."""
        return sh_colors(self.sh_degree if degree is None else degree, self.sh, self.means, camera_center)

    # ---- tensor plumbing ---------------------------------------------------------
    def _map(self, fn) -> "Gaussians2D":
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return replace(self, **{name: fn(value) for name, value in values.items() if value is not None})

    def to(self, *args, **kwargs) -> "Gaussians2D":
        """Copy on another device / dtype (``Tensor.to`` arguments)."""
        return self._map(lambda t: t.to(*args, **kwargs))

    def detach(self) -> "Gaussians2D":
        """Copy without autograd history (shares storage)."""
        return self._map(lambda t: t.detach())

    def clone(self) -> "Gaussians2D":
        """Deep copy of every tensor."""
        return self._map(lambda t: t.clone())

    def subset(self, index: Tensor) -> "Gaussians2D":
        """Surfels selected by a bool mask [N] or an index tensor."""
        return self._map(lambda t: t[index])

    def with_pbr(self, albedo_logits: Tensor, roughness_logits: Tensor, metallic_logits: Tensor) -> "Gaussians2D":
        """Copy with PBR logits attached ([N, 3], [N, 1], [N, 1])."""
        return replace(
            self, albedo_logits=albedo_logits, roughness_logits=roughness_logits, metallic_logits=metallic_logits
        )

    @property
    def device(self) -> torch.device:
        """Device of the tensors."""
        return self.means.device
