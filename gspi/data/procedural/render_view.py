"""Render one view of a procedural scene: supersampled split-sum input and exact GT maps.

Sampling: each pixel gets S x S stratified, jittered sub-pixel rays (stratum (a, b) at
((a + u) / S, (b + v) / S), u, v ~ U[0, 1) from a seeded torch Generator) plus one ray
through the pixel centre (the same ray as `eval.views.pixel_rays`).

Per view outputs (numpy float32, H x W):
* rgb: mean over all S^2 samples of the split-sum radiance (`eval.relight.split_sum`, capture
  environment, LINEAR albedo), misses contribute 0 (black background, anti-aliased edges).
* mask: True where more than half of the S^2 samples hit the surface (strict majority).
* albedo (linear mean over the hit samples, then sRGB-encoded), roughness, metallic: means over
  the hit samples; normal: mean of the hit samples' unit normals, renormalised.
* depth: camera-space z (OpenCV) of the pixel-centre hit, so unprojecting it along
  `pixel_rays` lands exactly on the surface; where the centre ray misses inside the mask (a
  silhouette pixel), the z of the hit sample nearest to the centre (the unprojected point is
  then off the surface by at most about one pixel footprint, never averaged across layers).
Everything except rgb is 0 outside the mask.

Device: the sub-pixel jitter and the rays are drawn on the CPU (the same rays on every device),
then traced, shaded and reduced on `device` (`render_views(..., device=)`); the maps come back
to the CPU as numpy arrays. On the CPU this is the code path of before, bit for bit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from eval.common.colorspace import linear_to_srgb
from eval.relight import split_sum
from eval.views import pixel_rays
from gspi.data.procedural.materials import evaluate_material
from gspi.data.procedural.sdf_shapes import ShapeSDF
from gspi.data.procedural.sphere_trace import sphere_trace

CHUNK = 1 << 16  # samples per material/shading batch (bounds memory of the Voronoi pattern)


@dataclass
class ViewRender:
    """Rendered view; arrays HxW(xC) float32 (mask bool). See module docstring."""

    rgb: np.ndarray
    albedo_srgb: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    rays: int
    sdf_evals: int
    outside_brdf: np.ndarray | None = None  # HxW bool: a sample hit a surface outside the BRDF
                                            # (glTF imports only; docs/DATA.md); None: there is none


def subpixel_rays(K: np.ndarray, w2c: np.ndarray, height: int, width: int, supersample: int,
                  generator: torch.Generator) -> Tensor:
    """World unit directions of the S x S jittered samples of every pixel.

    Returns:
        [H, W, S*S, 3] float32 (computed in float64 like `eval.views.pixel_rays`).
    """
    s = supersample
    a = torch.arange(s, dtype=torch.float64)
    sy, sx = torch.meshgrid(a, a, indexing="ij")
    jitter = torch.rand(height, width, s * s, 2, generator=generator, dtype=torch.float64)
    ox = (sx.reshape(-1) + jitter[..., 0]) / s
    oy = (sy.reshape(-1) + jitter[..., 1]) / s
    x = torch.arange(width, dtype=torch.float64)[None, :, None] + ox
    y = torch.arange(height, dtype=torch.float64)[:, None, None] + oy
    pix = torch.stack([x, y, torch.ones_like(x)], dim=-1)
    Kt = torch.as_tensor(K, dtype=torch.float64)
    R = torch.as_tensor(w2c, dtype=torch.float64)[:3, :3]
    dirs = (pix @ torch.linalg.inv(Kt).T) @ R
    return torch.nn.functional.normalize(dirs, dim=-1).float()


def _shade(shape: ShapeSDF, material: dict, pos: Tensor, normal: Tensor, dirs: Tensor,
           env) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Material + split-sum radiance of hit samples, in chunks. Returns rgb, albedo, r, m."""
    out = [[], [], [], []]
    for i in range(0, len(pos), CHUNK):
        sl = slice(i, i + CHUNK)
        mat = evaluate_material(material, shape.local(pos[sl]))
        rgb = split_sum(mat.albedo_linear, mat.roughness[:, None], mat.metallic[:, None],
                        normal[sl], -dirs[sl], env)
        for lst, val in zip(out, (rgb, mat.albedo_linear, mat.roughness, mat.metallic)):
            lst.append(val)
    return tuple(torch.cat(v) if v else pos.new_zeros(0) for v in out)  # type: ignore[return-value]


def _aggregate(height: int, width: int, s2: int, sub: Tensor, centre: Tensor, hit_sub: Tensor,
               hit_centre: Tensor, z_sub: Tensor, z_centre: Tensor, idx: Tensor, normal_h: Tensor,
               shaded: tuple[Tensor, Tensor, Tensor, Tensor]) -> dict[str, np.ndarray]:
    """Per-pixel reduction of one view's samples (see module docstring).

    idx: [n_hit] indices of the hit sub-samples in this view's [H*W*S^2] block, sorted.
    Computed on the device of the inputs; the maps are returned as CPU numpy arrays.
    """
    rgb_h, alb_h, rough_h, metal_h = shaded
    pix = torch.div(idx, s2, rounding_mode="floor")

    def pixel_sum(values: Tensor) -> Tensor:  # [n_hit, C] -> [H*W, C]
        acc = torch.zeros(height * width, values.shape[-1], dtype=torch.float64, device=pix.device)
        return acc.index_add_(0, pix, values.double())

    count = pixel_sum(torch.ones(len(idx), 1, device=pix.device))
    mask = count[:, 0] * 2 > s2
    denom = count.clamp_min(1.0)
    closeness = (sub.reshape(-1, s2, 3) * centre[:, None, :]).sum(-1)        # [HW, S^2]
    closeness = torch.where(hit_sub.reshape(-1, s2), closeness, torch.full_like(closeness, -2.0))
    nearest_z = z_sub.reshape(-1, s2).gather(1, closeness.argmax(dim=1, keepdim=True))
    depth = torch.where(hit_centre[:, None], z_centre[:, None], nearest_z).double()
    m = mask[:, None]

    def img(x: Tensor, c: int) -> np.ndarray:
        return torch.where(m, x, torch.zeros_like(x)).float().reshape(height, width, c).cpu().numpy()

    return {"rgb": (pixel_sum(rgb_h) / s2).float().reshape(height, width, 3).cpu().numpy(),
            "albedo_srgb": img(linear_to_srgb(pixel_sum(alb_h) / denom), 3),
            "roughness": img(pixel_sum(rough_h[:, None]) / denom, 1),
            "metallic": img(pixel_sum(metal_h[:, None]) / denom, 1),
            "normal": img(torch.nn.functional.normalize(pixel_sum(normal_h), dim=-1), 3),
            "depth": img(depth, 1), "mask": mask.reshape(height, width).cpu().numpy()}


def _render_group(shape: ShapeSDF, material: dict, cameras: list, height: int, width: int,
                  env, supersample: int, device: torch.device) -> list[ViewRender]:
    """Trace and shade the rays of several views in one batch (amortises per-step overhead)."""
    s2 = supersample * supersample
    blocks, origins = [], []
    for K, w2c, seed in cameras:
        gen = torch.Generator().manual_seed(int(seed))  # CPU: the same jitter on every device
        sub = subpixel_rays(K, w2c, height, width, supersample, gen).reshape(-1, 3).to(device)
        centre = pixel_rays(K, w2c, height, width).reshape(-1, 3).to(device)
        cam = torch.as_tensor(np.linalg.inv(w2c)[:3, 3], dtype=torch.float32, device=device)
        blocks.append((sub, centre))
        origins.append(cam.expand(len(sub) + len(centre), 3))
    dirs = torch.cat([torch.cat(b) for b in blocks])
    tr = sphere_trace(shape, torch.cat(origins).contiguous(), dirs, step_factor=shape.step_factor)
    n_sub, n_pix = height * width * s2, height * width
    flags = dict(dtype=torch.bool, device=device)
    is_sub = torch.cat([torch.cat([torch.ones(n_sub, **flags), torch.zeros(n_pix, **flags)])
                        for _ in cameras])
    hit_idx = torch.nonzero(tr.hit & is_sub).squeeze(-1)
    shaded = _shade(shape, material, tr.position[hit_idx], tr.normal[hit_idx], dirs[hit_idx], env)
    out = []
    for v, ((K, w2c, _), (sub, centre)) in enumerate(zip(cameras, blocks)):
        start = v * (n_sub + n_pix)
        bounds = torch.tensor([start, start + n_sub], device=device)
        lo, hi = torch.searchsorted(hit_idx, bounds).tolist()
        forward = torch.as_tensor(w2c[2, :3], dtype=torch.float32, device=device)
        sl_sub, sl_c = slice(start, start + n_sub), slice(start + n_sub, start + n_sub + n_pix)
        maps = _aggregate(height, width, s2, sub, centre, tr.hit[sl_sub], tr.hit[sl_c],
                          tr.t[sl_sub] * (sub @ forward), tr.t[sl_c] * (centre @ forward),
                          hit_idx[lo:hi] - start, tr.normal[hit_idx[lo:hi]],
                          tuple(x[lo:hi] for x in shaded))
        out.append(ViewRender(**maps, rays=n_sub + n_pix, sdf_evals=tr.steps // len(cameras)))
    return out


def render_views(shape: ShapeSDF, material: dict, cameras: list, height: int, width: int, *,
                 env, supersample: int, max_rays: int = 1 << 20,
                 device: torch.device | str = "cpu") -> list[ViewRender]:
    """Render several views of one scene (see module docstring).

    Args:
        shape: the scene's SDF. material: its material recipe.
        cameras: list of (K [3, 3], w2c [4, 4] OpenCV world-to-camera, jitter seed).
        env: capture environment for `split_sum` (PrefilteredEnvironment or [h, w, 3] tensor;
            best already on `device`, else its maps are copied there at every shading chunk).
        supersample: S (S x S samples per pixel).
        max_rays: views are traced together in groups of at most this many rays (at least one
            view per group); results do not depend on the grouping except through float
            vectorisation, so keep it fixed for byte-identical datasets.
        device: where the rays are traced and shaded (module docstring).
    Returns:
        One ViewRender per camera, in order.
    """
    per_view = height * width * (supersample * supersample + 1)
    group = max(1, max_rays // per_view)
    out: list[ViewRender] = []
    for i in range(0, len(cameras), group):
        out += _render_group(shape, material, cameras[i:i + group], height, width, env,
                             supersample, torch.device(device))
    return out


def render_view(shape: ShapeSDF, material: dict, K: np.ndarray, w2c: np.ndarray, height: int,
                width: int, *, env, supersample: int, seed: int) -> ViewRender:
    """Render one view; see `render_views`."""
    return render_views(shape, material, [(K, w2c, seed)], height, width, env=env,
                        supersample=supersample)[0]
