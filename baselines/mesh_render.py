"""Render UV-textured triangle meshes at canonical cameras on the CPU (numpy + torch).

Used by the MaterialAnything adapter, whose outputs are UV textures on a mesh. No mesh library
(pytorch3d, nvdiffrast, trimesh, pyrender) is installed here and none of them renders on a CPU
without an OpenGL context, hence this small vectorised rasteriser: per triangle, every pixel
centre of its screen bounding box is tested with edge functions, barycentrics are made
perspective-correct, and the nearest candidate per pixel wins (a z-buffer by sorting).

Conventions: cameras as in docs/FORMAT.md (OpenCV w2c, K with pixel centres at +0.5); OBJ
texture coordinates with v = 0 at the bottom row of the texture image (the OBJ/Blender/pytorch3d
convention); textures sampled bilinearly at pixel centres, coordinates outside [0, 1] clamped.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

CANDIDATE_BUDGET = 2_000_000  # candidate (triangle, pixel) pairs per vectorised chunk


class MeshError(ValueError):
    """An OBJ file is missing, unreadable or lacks texture coordinates."""


@dataclass(frozen=True)
class UVMesh:
    """A triangle mesh with per-corner texture coordinates."""

    vertices: np.ndarray  # [V, 3] float64, world units
    uvs: np.ndarray       # [T, 2] float64, (u, v) with v up
    faces: np.ndarray     # [F, 3] int64 indices into vertices
    face_uvs: np.ndarray  # [F, 3] int64 indices into uvs


def _index(token: str, count: int, path: Path, lineno: int) -> int:
    """OBJ index (1-based, negative = relative to the end) -> 0-based."""
    k = int(token)
    k = k - 1 if k > 0 else count + k
    if not 0 <= k < count:
        raise MeshError(f"{path}:{lineno}: index {token} out of range")
    return k


def read_obj(path: str | Path) -> UVMesh:
    """Read `v`, `vt` and `f v/vt[/vn]` records of an OBJ file; polygons are fan-triangulated.

    Raises:
        MeshError: the file is missing, a face has no texture coordinates, or there are no faces.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: mesh file not found")
    verts, uvs, faces, face_uvs = [], [], [], []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "vt":
            uvs.append([float(x) for x in parts[1:3]])
        elif parts[0] == "f":
            corners = [c.split("/") for c in parts[1:]]
            if any(len(c) < 2 or not c[1] for c in corners):
                raise MeshError(f"{path}:{lineno}: face without texture coordinates (need a "
                                "UV-mapped mesh, `f v/vt ...`)")
            vi = [_index(c[0], len(verts), path, lineno) for c in corners]
            ti = [_index(c[1], len(uvs), path, lineno) for c in corners]
            for k in range(1, len(corners) - 1):
                faces.append([vi[0], vi[k], vi[k + 1]])
                face_uvs.append([ti[0], ti[k], ti[k + 1]])
    if not faces:
        raise MeshError(f"{path}: no faces")
    return UVMesh(np.asarray(verts, np.float64), np.asarray(uvs, np.float64),
                  np.asarray(faces, np.int64), np.asarray(face_uvs, np.int64))


def _chunks(size: np.ndarray, budget: int):
    """Split triangles sorted by bounding-box size into runs of <= budget candidate pixels."""
    start, n = 0, len(size)
    while start < n:
        lo, hi = start + 1, n  # largest end with (end - start) * size[end - 1]^2 <= budget
        while lo < hi:
            mid = (lo + hi + 1) // 2
            lo, hi = (mid, hi) if (mid - start) * size[mid - 1] ** 2 <= budget else (lo, mid - 1)
        yield start, lo
        start = lo


def rasterize(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, w2c: np.ndarray,
              height: int, width: int, *, near: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Visible triangle and perspective-correct barycentrics at every pixel centre.

    Args:
        vertices: [V, 3] world. faces: [F, 3] indices. K: [3, 3]. w2c: [4, 4] OpenCV.
        near: triangles with a vertex closer than this (camera z) are dropped (not clipped).
    Returns:
        face_id: [H, W] int64, -1 where no triangle covers the pixel centre;
        bary: [H, W, 3] float64 barycentrics of the visible triangle (0 where none).
    """
    cam = vertices @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    proj = (cam / np.where(z > 0, z, 1.0)[:, None]) @ K.T
    keep = np.nonzero((z[faces] > near).all(1))[0]
    p = proj[faces[keep], :2]                          # [F, 3, 2] pixel coords
    zf = z[faces[keep]]                                # [F, 3]
    area = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
            - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    j0 = np.clip(np.ceil(p[..., 0].min(1) - 0.5), 0, width).astype(np.int64)
    j1 = np.clip(np.floor(p[..., 0].max(1) - 0.5), -1, width - 1).astype(np.int64)
    i0 = np.clip(np.ceil(p[..., 1].min(1) - 0.5), 0, height).astype(np.int64)
    i1 = np.clip(np.floor(p[..., 1].max(1) - 0.5), -1, height - 1).astype(np.int64)
    nw, nh = j1 - j0 + 1, i1 - i0 + 1
    ok = (np.abs(area) > 1e-12) & (nw > 0) & (nh > 0)
    keep, p, zf, area, j0, i0, nw, nh = (a[ok] for a in (keep, p, zf, area, j0, i0, nw, nh))
    size = np.maximum(nw, nh)
    order = np.argsort(size, kind="stable")
    found = []  # (pixel, depth, face, b0, b1, b2)
    for s, e in _chunks(size[order], CANDIDATE_BUDGET):
        idx = order[s:e]
        m = int(size[idx].max())
        di, dj = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        di, dj = di.reshape(1, -1), dj.reshape(1, -1)
        valid = (di < nh[idx, None]) & (dj < nw[idx, None])
        ii, jj = i0[idx, None] + di, j0[idx, None] + dj
        qx, qy = jj + 0.5, ii + 0.5
        pt = p[idx]

        def edge(a, b):  # [n, m*m]: twice the signed area of (p_a, p_b, q)
            return ((pt[:, b, 0:1] - pt[:, a, 0:1]) * (qy - pt[:, a, 1:2])
                    - (pt[:, b, 1:2] - pt[:, a, 1:2]) * (qx - pt[:, a, 0:1]))

        w = np.stack([edge(1, 2), edge(2, 0), edge(0, 1)], -1) / area[idx, None, None]
        inside = valid & (w >= -1e-9).all(-1)
        t, c = np.nonzero(inside)
        wz = w[t, c] / zf[idx][t]                     # perspective correction: w_i / z_i
        inv_depth = wz.sum(-1)
        found.append((ii[t, c] * width + jj[t, c], 1.0 / inv_depth, keep[idx][t],
                       wz / inv_depth[:, None]))
    face_id = np.full(height * width, -1, np.int64)
    bary = np.zeros((height * width, 3))
    if found:
        pix, depth, face, b = (np.concatenate(x) for x in zip(*found))
        first = np.lexsort((depth, pix))               # nearest candidate first per pixel
        pix_sorted = pix[first]
        _, winner = np.unique(pix_sorted, return_index=True)
        sel = first[winner]
        face_id[pix[sel]], bary[pix[sel]] = face[sel], b[sel]
    return face_id.reshape(height, width), bary.reshape(height, width, 3)


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup with pixel centres, v up, coordinates clamped to the border.

    Args:
        texture: [Ht, Wt, C] values. uv: [N, 2] texture coordinates.
    Returns:
        [N, C] float64.
    """
    tex = torch.from_numpy(np.ascontiguousarray(texture, np.float64)).permute(2, 0, 1)[None]
    grid = torch.from_numpy(np.stack([2.0 * uv[:, 0] - 1.0, 1.0 - 2.0 * uv[:, 1]], -1))
    out = torch.nn.functional.grid_sample(tex, grid[None, None], mode="bilinear",
                                          padding_mode="border", align_corners=False)
    return out[0, :, 0].T.numpy()


def render_uv_maps(mesh: UVMesh, textures: dict[str, np.ndarray], K: np.ndarray,
                   w2c: np.ndarray, height: int, width: int) -> tuple[np.ndarray, dict]:
    """Texture values of the visible surface at every pixel centre.

    Args:
        textures: name -> [Ht, Wt, C] UV texture (any sizes).
    Returns:
        coverage: [H, W] bool; maps: name -> [H, W, C] float64 (0 where not covered).
    """
    face_id, bary = rasterize(mesh.vertices, mesh.faces, K, w2c, height, width)
    covered = face_id >= 0
    corner_uv = mesh.uvs[mesh.face_uvs[face_id[covered]]]      # [N, 3, 2]
    uv = (bary[covered][..., None] * corner_uv).sum(1)
    maps = {}
    for name, tex in textures.items():
        out = np.zeros((height, width, tex.shape[-1]))
        out[covered] = sample_texture(tex, uv)
        maps[name] = out
    return covered, maps
