"""Pinhole-camera helpers in the OpenCV / gsplat convention.

World-to-camera matrices ``w2c`` [..., 4, 4] map world points to camera axes
x right, y down, z forward; intrinsics ``K`` [..., 3, 3] map camera points to
pixels whose centres sit at (j + 0.5, i + 0.5). Depths are camera z (not ray
length). All functions are pure and batch over leading dimensions.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor


def look_at(camera_center: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """World-to-camera matrix of a camera at ``camera_center`` looking at ``target``.

    Image "up" (-y) points along ``up`` projected onto the image plane. When the
    viewing direction is (anti)parallel to ``up`` another world axis is used as up,
    so poles of a view sphere still get a valid camera.

    Args:
        camera_center: [..., 3] camera position in world space.
        target: [..., 3] point the optical axis passes through.
        up: [..., 3] world up direction.

    Returns:
        [..., 4, 4] world-to-camera matrix (OpenCV axes).
    """
    camera_center, target, up = torch.broadcast_tensors(camera_center, target, up)
    forward = F.normalize(target - camera_center, dim=-1)
    right = torch.linalg.cross(forward, up, dim=-1)
    degenerate = right.norm(dim=-1, keepdim=True) < 1e-6 * up.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    ex = torch.zeros_like(up)
    ex[..., 0] = 1.0
    ey = torch.zeros_like(up)
    ey[..., 1] = 1.0
    alt_up = torch.where((forward[..., :1].abs() < 0.9), ex, ey)
    right = torch.where(degenerate, torch.linalg.cross(forward, alt_up, dim=-1), right)
    right = F.normalize(right, dim=-1)
    down = torch.linalg.cross(forward, right, dim=-1)
    rot_c2w = torch.stack([right, down, forward], dim=-1)  # columns = camera axes in world
    rot_w2c = rot_c2w.transpose(-1, -2)
    w2c = torch.zeros(camera_center.shape[:-1] + (4, 4), dtype=camera_center.dtype, device=camera_center.device)
    w2c[..., :3, :3] = rot_w2c
    w2c[..., :3, 3] = -(rot_w2c @ camera_center[..., None])[..., 0]
    w2c[..., 3, 3] = 1.0
    return w2c


def intrinsics_from_fov(fov_x: float, width: int, height: int, *, dtype=torch.float32, device=None) -> Tensor:
    """Square-pixel intrinsics with ``cx = W / 2``, ``cy = H / 2``.

    Args:
        fov_x: horizontal field of view in radians.
        width: image width in pixels.
        height: image height in pixels.

    Returns:
        [3, 3] K with ``fx = fy = W / (2 tan(fov_x / 2))``.
    """
    focal = width / (2.0 * math.tan(fov_x / 2.0))
    rows = [[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]]
    return torch.tensor(rows, dtype=dtype, device=device)


def camera_centers(w2c: Tensor) -> Tensor:
    """[..., 3] camera centres in world space, ``-R^T t``, of w2c [..., 4, 4]."""
    rot, t = w2c[..., :3, :3], w2c[..., :3, 3]
    return -(rot.transpose(-1, -2) @ t[..., None])[..., 0]


def _camera_points(K: Tensor, height: int, width: int) -> Tensor:
    """[..., H, W, 3] camera-space points at z = 1 through the pixel centres."""
    ys = torch.arange(height, dtype=K.dtype, device=K.device) + 0.5
    xs = torch.arange(width, dtype=K.dtype, device=K.device) + 0.5
    y, x = torch.meshgrid(ys, xs, indexing="ij")
    fx, fy = K[..., 0, 0, None, None], K[..., 1, 1, None, None]
    cx, cy = K[..., 0, 2, None, None], K[..., 1, 2, None, None]
    skew = K[..., 0, 1, None, None]
    yc = (y - cy) / fy
    xc = (x - cx - skew * yc) / fx
    return torch.stack([xc, yc, torch.ones_like(xc)], dim=-1)


def pixel_rays(K: Tensor, w2c: Tensor, height: int, width: int) -> Tensor:
    """World-space unit ray directions through pixel centres.

    Args:
        K: [..., 3, 3] intrinsics.
        w2c: [..., 4, 4] world-to-camera.
        height: image height H.
        width: image width W.

    Returns:
        [..., H, W, 3] unit directions (origin: :func:`camera_centers`).
    """
    dirs_cam = _camera_points(K, height, width)
    rot_c2w = w2c[..., :3, :3].transpose(-1, -2)
    return F.normalize(torch.einsum("...ij,...hwj->...hwi", rot_c2w, dirs_cam), dim=-1)


def unproject(depth: Tensor, K: Tensor, w2c: Tensor) -> Tensor:
    """World points of a z-depth map.

    Args:
        depth: [..., H, W] or [..., H, W, 1] camera z per pixel (not ray length).
        K: [..., 3, 3] intrinsics.
        w2c: [..., 4, 4] world-to-camera.

    Returns:
        [..., H, W, 3] world-space points ``c + R^T (z K^-1 [x, y, 1])``.
    """
    if depth.dim() >= 3 and depth.shape[-1] == 1:  # [..., H, W, 1] (images with W = 1 unsupported)
        depth = depth[..., 0]
    height, width = depth.shape[-2:]
    pts_cam = _camera_points(K, height, width) * depth[..., None]
    rot_c2w = w2c[..., :3, :3].transpose(-1, -2)
    return torch.einsum("...ij,...hwj->...hwi", rot_c2w, pts_cam) + camera_centers(w2c)[..., None, None, :]
