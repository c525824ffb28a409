"""UV textures of a triangle mesh looked up at the canonical cameras' pixel centres (CPU).

Used by the MaterialAnything adapter, whose outputs are UV textures on a mesh: the visible
surface at each pixel centre comes from the project's one mesh ray caster
(gspi.data.assets.mesh_render: trimesh, Embree when installed; hits and barycentrics in float64,
equal to an analytic reference within 1e-9, tests/test_baselines_mesh_render.py), the texture
coordinates are interpolated with its barycentrics and the textures sampled here.

Conventions: cameras as in docs/FORMAT.md (OpenCV w2c, K with pixel centres at +0.5); OBJ
texture coordinates with v = 0 at the bottom row of the texture image (the OBJ/Blender/pytorch3d
convention); textures sampled bilinearly at pixel centres, coordinates outside [0, 1] clamped.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from eval.views import pixel_rays


class MeshError(ValueError):
    """An OBJ file is missing, unreadable or lacks texture coordinates."""


@dataclass(frozen=True)
class UVMesh:
    """A triangle mesh with per-corner texture coordinates."""

    vertices: np.ndarray  # [V, 3] float64, world units
    uvs: np.ndarray       # [T, 2] float64, (u, v) with v up
    faces: np.ndarray     # [F, 3] int64 indices into vertices
    face_uvs: np.ndarray  # [F, 3] int64 indices into uvs

    @cached_property
    def intersector(self):
        """The ray caster over this mesh (gspi.data.assets.mesh_render.ray_intersector), built once
        per mesh: every view of it casts against the same acceleration structure."""
        import trimesh

        from gspi.data.assets.mesh_render import ray_intersector

        return ray_intersector(trimesh.Trimesh(self.vertices, self.faces, process=False))


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


def visible_surface(mesh: UVMesh, K: np.ndarray, w2c: np.ndarray, height: int, width: int
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Visible triangle and its barycentrics at every pixel centre: the nearest hit of the
    pixel-centre ray (float64 directions), cast by the project's one mesh ray caster
    (``gspi.data.assets.mesh_render.closest_hits``: trimesh, Embree when installed).

    Args:
        K: [3, 3]. w2c: [4, 4] OpenCV.
    Returns:
        face_id: [H, W] int64, -1 where no triangle covers the pixel centre;
        bary: [H, W, 3] float64 barycentrics of the visible triangle (0 where none).
    """
    from gspi.data.assets.mesh_render import closest_hits

    dirs = pixel_rays(K, w2c, height, width, dtype=torch.float64).reshape(-1, 3).numpy()
    origins = np.broadcast_to(np.linalg.inv(w2c)[:3, 3], dirs.shape).copy()
    ray, tri, _, bary = closest_hits(mesh.intersector, mesh.vertices, mesh.faces, origins, dirs)
    face_id = np.full(height * width, -1, np.int64)
    weights = np.zeros((height * width, 3))
    face_id[ray], weights[ray] = tri, bary
    return face_id.reshape(height, width), weights.reshape(height, width, 3)


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
    face_id, bary = visible_surface(mesh, K, w2c, height, width)
    covered = face_id >= 0
    corner_uv = mesh.uvs[mesh.face_uvs[face_id[covered]]]      # [N, 3, 2]
    uv = (bary[covered][..., None] * corner_uv).sum(1)
    maps = {}
    for name, tex in textures.items():
        out = np.zeros((height, width, tex.shape[-1]))
        out[covered] = sample_texture(tex, uv)
        maps[name] = out
    return covered, maps
