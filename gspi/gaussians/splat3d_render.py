"""A dense reference renderer of 3D Gaussian splats (EWA splatting, as 3DGS renders them).

What a 3DGS file looks like before `gspi.gaussians.splat3d.flatten_3dgs` turns it into
surfels: each Gaussian's covariance ``R S S^T R^T`` is projected through the camera's local
affine approximation (``Sigma' = J W Sigma W^T J^T``, Zwicker et al.'s EWA, 3DGS Eq. 5), widened by
3DGS's low-pass (0.3 px^2 on the diagonal), and the splats are alpha-composited front to back
by centre depth with ``alpha = min(0.99, o exp(-d^T Sigma'^-1 d / 2))``, dropped below 1/255,
as graphdeco-inria's rasterizer does (its tile lists and early termination at T < 1e-4 are
left out: they change nothing above float rounding).

It exists to measure what flattening loses (docs/DATA.md "3DGS input"; tests/test_splat3d.py):
gsplat's 3DGS rasterizer is CUDA-only, and no CPU package renders 3DGS. Dense over
(Gaussian, pixel) pairs, forward only, chunked over pixels: for test assets of a few thousand
Gaussians at 64-128 px, not for training.
"""
from __future__ import annotations

import torch
from torch import Tensor

from gspi.gaussians.projection import quat_to_rotmat

ALPHA_MIN, ALPHA_MAX = 1.0 / 255.0, 0.99   # graphdeco-inria's forward.cu
LOW_PASS = 0.3                             # px^2 added to the projected covariance's diagonal


def projected_covariance(means: Tensor, quats: Tensor, scales: Tensor, viewmat: Tensor, K: Tensor
                         ) -> tuple[Tensor, Tensor, Tensor]:
    """(centre [N, 2] px, covariance [N, 2, 2] px^2 with the low-pass, camera depth [N]) of 3D
    Gaussians (means [N, 3], quats [N, 4] w x y z, scales [N, 3] activated) in one OpenCV camera."""
    rot = quat_to_rotmat(torch.nn.functional.normalize(quats, dim=-1))
    cov = rot @ torch.diag_embed(scales ** 2) @ rot.transpose(-1, -2)
    w = viewmat[:3, :3]
    cam = means @ w.T + viewmat[:3, 3]
    x, y, z = cam.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    zero = torch.zeros_like(z)
    jac = torch.stack([torch.stack([fx / z, zero, -fx * x / z ** 2], -1),
                       torch.stack([zero, fy / z, -fy * y / z ** 2], -1)], -2)  # [N, 2, 3]
    cov2d = jac @ w @ cov @ w.T @ jac.transpose(-1, -2)
    cov2d = cov2d + LOW_PASS * torch.eye(2, dtype=cov2d.dtype)
    centre = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)
    return centre, cov2d, z


@torch.no_grad()
def render_3dgs(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
                viewmats: Tensor, Ks: Tensor, width: int, height: int, *, near: float = 0.01,
                pixel_chunk: int = 4096) -> tuple[Tensor, Tensor]:
    """(colour [C, H, W, D], alpha [C, H, W, 1]) of 3D Gaussians in C cameras on a black background.

    Args:
        means, quats, scales: [N, 3], [N, 4] (w x y z), [N, 3] activated scales.
        opacities: [N] activated. colors: [N, D] or [C, N, D] (e.g. SH evaluated per view).
        viewmats, Ks: [C, 4, 4] world-to-camera (OpenCV), [C, 3, 3].
    """
    jj, ii = torch.meshgrid(torch.arange(width, dtype=torch.float64) + 0.5,
                            torch.arange(height, dtype=torch.float64) + 0.5, indexing="xy")
    pixels = torch.stack([jj.reshape(-1), ii.reshape(-1)], -1)  # pixel centres, row-major
    out_rgb, out_alpha = [], []
    for c in range(len(viewmats)):
        col = colors[c] if colors.dim() == 3 else colors
        centre, cov2d, z = projected_covariance(means.double(), quats.double(), scales.double(),
                                                viewmats[c].double(), Ks[c].double())
        keep = z > near
        order = torch.argsort(z[keep], stable=True)
        centre, conic = centre[keep][order], torch.linalg.inv(cov2d[keep][order])
        opacity, col = opacities.double()[keep][order], col.double()[keep][order]
        rgb, alpha = [], []
        for start in range(0, len(pixels), pixel_chunk):
            d = pixels[start:start + pixel_chunk, None, :] - centre[None]          # [P, N, 2]
            power = -0.5 * torch.einsum("pni,nij,pnj->pn", d, conic, d)
            a = torch.clamp(opacity[None] * torch.exp(power), max=ALPHA_MAX)
            a = torch.where(a < ALPHA_MIN, torch.zeros_like(a), a)
            trans = torch.cumprod(torch.cat([torch.ones_like(a[:, :1]), 1.0 - a[:, :-1]], 1), 1)
            weights = a * trans
            rgb.append(weights @ col)
            alpha.append(weights.sum(1, keepdim=True))
        out_rgb.append(torch.cat(rgb).reshape(height, width, -1))
        out_alpha.append(torch.cat(alpha).reshape(height, width, 1))
    return torch.stack(out_rgb).float(), torch.stack(out_alpha).float()
