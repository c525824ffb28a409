"""Stanford-ORB's per-view environment maps <-> the layout's world lat-long maps.

Stanford-ORB stores one environment map per test image (`ground_truth/<capture>/env_map/
<id>.exr`) in that image's camera frame (StanfordORB/Stanford-ORB orb/utils/env_map.py,
`env_map_to_cam_to_world_by_convention`): texel (r, c) of an H x W map looks along the
Blender/OpenGL camera-space direction

    phi = r pi / (H - 1),  theta = -pi/2 + c 2 pi / (W - 1)       (np.linspace, end points included)
    d_cam = (-cos theta sin phi, cos phi, -sin theta sin phi)      (centre column = camera forward -Z)

and a world direction d is looked up at d_cam = R_c2w^T d, bilinearly (x wraps). The layout's
maps are world-space Z-up (eval.envmap). Converting needs the view's camera, so the world map
of a view is made with that view's c2w; two resamplings (import then export) are not exact
(bilinear each way, and the two texel grids differ by the end-point convention above).
"""
from __future__ import annotations

import numpy as np
import torch

from eval.envmap import latlong_directions, sample_latlong


def orb_directions(height: int, width: int) -> np.ndarray:
    """[H, W, 3] camera-space (OpenGL) direction of every texel of an ORB map."""
    theta, phi = np.meshgrid(np.linspace(-0.5 * np.pi, 1.5 * np.pi, width), np.linspace(0.0, np.pi, height))
    return np.stack([-np.cos(theta) * np.sin(phi), np.cos(phi), -np.sin(theta) * np.sin(phi)], -1)


def sample_orb(env: np.ndarray, d_cam: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an ORB map [H, W, 3] along camera-space directions [..., 3]."""
    h, w = env.shape[:2]
    d = d_cam / np.linalg.norm(d_cam, axis=-1, keepdims=True)
    y = np.arccos(np.clip(d[..., 1], -1.0, 1.0)) / np.pi * (h - 1)
    x = (np.arctan2(d[..., 0], -d[..., 2]) + np.pi) / (2 * np.pi) * (w - 1)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 1)
    y1, fy = np.clip(y0 + 1, 0, h - 1), (y - np.floor(y))[..., None]
    x0 = np.floor(x).astype(int)
    fx = (x - x0)[..., None]
    x0, x1 = x0 % w, (x0 + 1) % w
    top = env[y0, x0] * (1 - fx) + env[y0, x1] * fx
    bottom = env[y1, x0] * (1 - fx) + env[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def orb_to_world(env_orb: np.ndarray, c2w_gl: np.ndarray, height: int | None = None) -> np.ndarray:
    """The layout's world lat-long map [height, 2 height, 3] of one view's ORB map."""
    height = height or env_orb.shape[0]
    d_world = latlong_directions(height, 2 * height, dtype=torch.float64).numpy()
    return sample_orb(env_orb, d_world @ np.asarray(c2w_gl)[:3, :3])  # row form of R^T d


def world_to_orb(env_world: np.ndarray, c2w_gl: np.ndarray, height: int | None = None) -> np.ndarray:
    """One view's ORB map [height, 2 height, 3] of a world lat-long map of the layout."""
    height = height or env_world.shape[0]
    d_world = orb_directions(height, 2 * height) @ np.asarray(c2w_gl)[:3, :3].T  # R d_cam
    return sample_latlong(torch.from_numpy(env_world), torch.from_numpy(d_world)).numpy()
