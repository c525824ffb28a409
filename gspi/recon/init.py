"""Initial surfels: points on the visual hull of the input masks.

For random foreground pixels of every input view, the ray is marched from the camera
and the first sample that projects inside the foreground mask of every view (the visual
hull) is kept, refined by bisection. Each point gets the linear colour of its pixel
(SH DC), a normal facing its source camera, opacity 0.1 and an isotropic scale from
the mean distance to its three nearest neighbours (3DGS's rule).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from gspi.gaussians.cameras import camera_centers, pixel_rays
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.sh import num_sh_bases, rgb_to_sh
from gspi.recon.data import SceneViews


def in_hull(points: Tensor, views: SceneViews, min_views: int | None = None) -> Tensor:
    """[P] bool: the point projects onto foreground in at least ``min_views`` views (default all).

    A projection outside an image or behind its camera counts as background.
    """
    v, h, w = views.masks.shape
    pc = torch.einsum("vij,pj->vpi", views.viewmats[:, :3, :3], points) + views.viewmats[:, None, :3, 3]
    uvw = torch.einsum("vij,vpj->vpi", views.Ks, pc)
    z = uvw[..., 2]
    ok = z > 1e-6
    zs = torch.where(ok, z, torch.ones_like(z))
    col = torch.floor(uvw[..., 0] / zs).long()
    row = torch.floor(uvw[..., 1] / zs).long()
    ok &= (col >= 0) & (col < w) & (row >= 0) & (row < h)
    flat = (torch.arange(v, device=points.device)[:, None] * h + row.clamp(0, h - 1)) * w + col.clamp(0, w - 1)
    fg = views.masks.reshape(-1)[flat] & ok
    need = v if min_views is None else min_views
    return fg.sum(0) >= need


def _quat_from_rotmat(rot: Tensor) -> Tensor:
    """(w, x, y, z) unit quaternions of rotation matrices [N, 3, 3] (Shepperd's method)."""
    m = rot
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cand = torch.stack([
        torch.stack([1 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1),
        torch.stack([m[:, 2, 1] - m[:, 1, 2], 1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2], m[:, 0, 1] + m[:, 1, 0],
                     m[:, 0, 2] + m[:, 2, 0]], -1),
        torch.stack([m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2],
                     m[:, 1, 2] + m[:, 2, 1]], -1),
        torch.stack([m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1],
                     1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2]], -1),
    ], 1)  # [N, 4 candidates, 4]
    best = torch.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], -1).argmax(-1)
    q = cand[torch.arange(len(m), device=m.device), best]
    return torch.nn.functional.normalize(q, dim=-1)


def facing_quats(normals: Tensor) -> Tensor:
    """Quaternions whose rotation column 2 (the surfel normal) is ``normals`` [N, 3]."""
    n = torch.nn.functional.normalize(normals, dim=-1)
    helper = torch.zeros_like(n)
    helper[:, 0] = 1.0
    alt = torch.zeros_like(n)
    alt[:, 1] = 1.0
    helper = torch.where((n[:, :1].abs() > 0.9), alt, helper)
    t1 = torch.nn.functional.normalize(torch.linalg.cross(helper, n, dim=-1), dim=-1)
    t2 = torch.linalg.cross(n, t1, dim=-1)
    return _quat_from_rotmat(torch.stack([t1, t2, n], dim=-1))


def knn_mean_dist(points: Tensor, k: int = 3, chunk: int = 2048) -> Tensor:
    """[P] root mean squared distance to the k nearest other points (3DGS's scale init)."""
    out = []
    for start in range(0, len(points), chunk):
        d2 = torch.cdist(points[start:start + chunk], points).pow(2)
        rows = torch.arange(d2.shape[0], device=d2.device)
        d2[rows, rows + start] = float("inf")
        kk = min(k, max(len(points) - 1, 1))
        out.append(d2.topk(kk, dim=1, largest=False).values.mean(1))
    return torch.cat(out).clamp_min(1e-12).sqrt()


def visual_hull_points(views: SceneViews, num_points: int, *, samples_per_ray: int = 96,
                       bisect_steps: int = 6, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor, Tensor]:
    """Points on the visual hull seen from the input views.

    Returns:
        points [P, 3], colours [P, 3] (linear radiance of the source pixel), directions [P, 3]
        (unit ray directions from the source camera), P <= num_points (rays that miss the hull
        are dropped, e.g. where masks disagree).

    Only views that see some foreground carve the hull: a view with an empty mask sees no
    silhouette (a single-sided surface seen from behind is culled: glTF imports), and letting
    it carve would empty the hull of every flat single-sided asset.
    """
    v, h, w = views.masks.shape
    carving = views.select(views.masks.reshape(v, -1).any(1))
    centers = camera_centers(views.viewmats)  # [V, 3]
    dirs_all = pixel_rays(views.Ks, views.viewmats, h, w)  # [V, H, W, 3]
    # march over the depth range of a ball around the point nearest to all optical axes
    axes = views.viewmats[:, 2, :3]  # camera z axis in world
    eye = torch.eye(3, dtype=centers.dtype, device=centers.device)
    proj = eye[None] - axes[:, :, None] * axes[:, None, :]
    target = torch.linalg.lstsq(proj.sum(0), (proj @ centers[..., None]).sum(0)).solution[:, 0]
    dist = (centers - target).norm(dim=-1)
    half_fov = torch.atan(0.5 * max(h, w) / torch.minimum(views.Ks[:, 0, 0], views.Ks[:, 1, 1]))
    radius = float((dist * torch.sin(half_fov)).min()) * math.sqrt(2.0)
    per_view = max(1, math.ceil(2 * num_points / v))
    pts, cols, dirs = [], [], []
    t_lin = torch.linspace(0.0, 1.0, samples_per_ray, device=centers.device)
    for i in range(v):
        fg = torch.nonzero(views.masks[i].reshape(-1))[:, 0]
        if len(fg) == 0:
            continue
        pick = fg[torch.randperm(len(fg), generator=generator)[:per_view].to(fg.device)]
        d = dirs_all[i].reshape(-1, 3)[pick]  # [R, 3]
        t0, t1 = max(float(dist[i]) - radius, 1e-3), float(dist[i]) + radius
        t = t0 + (t1 - t0) * t_lin  # [S]
        samples = centers[i] + t[None, :, None] * d[:, None, :]  # [R, S, 3]
        inside = in_hull(samples.reshape(-1, 3), carving).reshape(len(pick), -1)
        hit = inside.any(1)
        first = inside.float().argmax(1)
        lo = t[(first - 1).clamp_min(0)]
        hi = t[first]
        for _ in range(bisect_steps):  # the hull boundary lies in (lo, hi]
            mid = 0.5 * (lo + hi)
            m_in = in_hull(centers[i] + mid[:, None] * d, carving)
            hi = torch.where(m_in, mid, hi)
            lo = torch.where(m_in, lo, mid)
        p = centers[i] + hi[:, None] * d
        pts.append(p[hit])
        cols.append(views.images[i].reshape(-1, 3)[pick][hit])
        dirs.append(d[hit])
    if not pts or sum(len(p) for p in pts) == 0:
        raise ValueError("visual hull is empty: the masks of the input views do not overlap")
    pts, cols, dirs = torch.cat(pts), torch.cat(cols), torch.cat(dirs)
    keep = torch.randperm(len(pts), generator=generator)[:num_points].to(pts.device)
    return pts[keep], cols[keep], dirs[keep]


def init_gaussians(views: SceneViews, num_points: int, sh_degree: int, *, init_opacity: float = 0.1,
                   scale_factor: float = 1.0, generator: torch.Generator | None = None) -> Gaussians2D:
    """Surfels on the visual hull (see the module docstring); SH beyond DC start at zero."""
    pts, cols, dirs = visual_hull_points(views, num_points, generator=generator)
    n = len(pts)
    return Gaussians2D(
        means=pts.float(),
        quats=facing_quats(-dirs).float(),
        log_scales=torch.log(knn_mean_dist(pts) * scale_factor)[:, None].repeat(1, 2).float(),
        opacity_logits=torch.full((n,), math.log(init_opacity / (1.0 - init_opacity)), device=pts.device),
        sh_dc=rgb_to_sh(cols.float().clamp(0.0, 4.0))[:, None, :],
        sh_rest=torch.zeros(n, num_sh_bases(sh_degree) - 1, 3, device=pts.device),
    )
