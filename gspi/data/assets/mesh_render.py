"""Render views of a textured PBR triangle mesh: supersampled split-sum input and exact GT maps.

The mesh counterpart of `gspi.data.procedural.render_view` (same samples, same per-pixel reduction, same
`ViewRender`): rays are cast with trimesh (Embree through `embreex` when installed, else
trimesh's pure-numpy intersector), the material is looked up at the hit (`gspi.data.assets.gltf`
module docstring: factors x bilinear texture at the barycentric UV), normals are the
barycentric interpolation of the vertex normals (face normals where a primitive has none),
turned towards the ray when a back face is hit. Normal maps are not applied. Alpha MASK
cut-outs and single-sided culling decide which hits are drawn (`drawn`); a ray goes on past
the others. Views of an asset with BLEND or KHR_materials_* materials carry `outside_brdf`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from eval.common.colorspace import srgb_to_linear
from eval.relight import split_sum
from eval.views import pixel_rays
# `_aggregate` is render_view's per-pixel reduction; reused so both renderers reduce alike.
from gspi.data.procedural.render_view import ViewRender, _aggregate, subpixel_rays
from gspi.data.assets.gltf import CLAMP_TO_EDGE, MIRRORED_REPEAT, REPEAT, Asset, Material

MAX_LAYERS = 16      # culled / cut-out surfaces a ray passes before it is called a miss
LAYER_EPS = 1e-5     # a passed ray restarts this far beyond the surface (unit-sphere scene)


@dataclass
class PBRMesh:
    """All primitives of an asset in one triangle soup, in the unit frame.

    vertices [V, 3], faces [F, 3], normals [V, 3] (zero rows: use the face normal),
    uv [V, 2] (zeros where absent), face_material [F] index into `materials`.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray
    face_material: np.ndarray
    materials: list[Material]
    center: np.ndarray
    scale: float
    uv1: np.ndarray | None = None    # [V, 2] TEXCOORD_1 (zeros where absent), None if no primitive has it
    color: np.ndarray | None = None  # [V, 3] COLOR_0 (ones where absent), None if no primitive has it
    alpha: np.ndarray | None = None  # [V] COLOR_0's alpha (ones where absent), None if none has it

    def trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)


def unit_frame_mesh(asset: Asset, radius: float = 1.0) -> PBRMesh:
    """Concatenate the primitives; centre the bounding box at the origin, farthest vertex at
    `radius` (the benchmark's unit sphere)."""
    verts, faces, normals, uvs, uv1s, colors, alphas, fmat, mats = [], [], [], [], [], [], [], [], []
    offset = 0
    for prim in asset.primitives:
        if all(m is not prim.material for m in mats):
            mats.append(prim.material)
        k = next(i for i, m in enumerate(mats) if m is prim.material)
        nv = len(prim.vertices)
        verts.append(prim.vertices)
        faces.append(prim.faces + offset)
        normals.append(prim.normals if prim.normals is not None else np.zeros((nv, 3)))
        uvs.append(prim.uv if prim.uv is not None else np.zeros((nv, 2)))
        uv1s.append(prim.uv1 if prim.uv1 is not None else np.zeros((nv, 2)))
        colors.append(prim.color if prim.color is not None else np.ones((nv, 3)))
        alphas.append(prim.alpha if prim.alpha is not None else np.ones(nv))
        fmat.append(np.full(len(prim.faces), k))
        offset += nv
    v = np.concatenate(verts)
    center = 0.5 * (v.min(0) + v.max(0))
    scale = radius / max(float(np.linalg.norm(v - center, axis=-1).max()), 1e-12)
    has_uv1 = any(p.uv1 is not None for p in asset.primitives)
    has_color = any(p.color is not None for p in asset.primitives)
    has_alpha = any(p.alpha is not None for p in asset.primitives)
    return PBRMesh((v - center) * scale, np.concatenate(faces), np.concatenate(normals),
                   np.concatenate(uvs), np.concatenate(fmat), mats, center, scale,
                   uv1=np.concatenate(uv1s) if has_uv1 else None,
                   color=np.concatenate(colors) if has_color else None,
                   alpha=np.concatenate(alphas) if has_alpha else None)


def wrap_index(i: np.ndarray, n: int, mode: int) -> np.ndarray:
    """Texel indices wrapped as a glTF sampler says: REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT."""
    if mode == CLAMP_TO_EDGE:
        return np.clip(i, 0, n - 1)
    if mode == MIRRORED_REPEAT:
        k = np.mod(i, 2 * n)
        return np.where(k < n, k, 2 * n - 1 - k)
    return np.mod(i, n)


def sample_texture(tex: np.ndarray, uv: np.ndarray, wrap: tuple[int, int] = (REPEAT, REPEAT)) -> np.ndarray:
    """Bilinear lookup, glTF texel convention: pixel (x, y) = (u W - 0.5, v H - 0.5); texels
    outside the image wrapped by ``wrap`` = (wrapS, wrapT) (REPEAT by default)."""
    h, w = tex.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xs = (wrap_index(x0, w, wrap[0]), wrap_index(x0 + 1, w, wrap[0]))
    ys = (wrap_index(y0, h, wrap[1]), wrap_index(y0 + 1, h, wrap[1]))
    top = tex[ys[0], xs[0]] * (1 - fx) + tex[ys[0], xs[1]] * fx
    bot = tex[ys[1], xs[0]] * (1 - fx) + tex[ys[1], xs[1]] * fx
    return top * (1 - fy) + bot * fy


def _interpolate(mesh: PBRMesh, attr: np.ndarray, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """A per-vertex attribute at hits (triangle [N], barycentrics [N, 3])."""
    return np.einsum("nk,nk...->n...", bary, attr[mesh.faces[tri]])


def _lookup(mesh: PBRMesh, tex: np.ndarray, sampling, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """A material texture at hits: its UV set, KHR_texture_transform, wrap modes, bilinear."""
    uv_attr = mesh.uv1 if sampling.texcoord == 1 else mesh.uv
    uv = sampling.apply(_interpolate(mesh, uv_attr, tri, bary))
    return sample_texture(tex, uv, (sampling.wrap_s, sampling.wrap_t))


def coverage_alpha(mesh: PBRMesh, mat: Material, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """glTF alpha at hits on `mat`: baseColorFactor.a x baseColorTexture.a x COLOR_0.a, [N]."""
    alpha = np.full(len(tri), mat.base_alpha)
    if mat.base_color_alpha_texture is not None:
        tex = mat.base_color_alpha_texture[..., None]
        alpha = alpha * _lookup(mesh, tex, mat.base_color_sampling, tri, bary)[:, 0]
    if mesh.alpha is not None:
        alpha = alpha * _interpolate(mesh, mesh.alpha, tri, bary)
    return alpha


def evaluate_materials(mesh: PBRMesh, tri: np.ndarray, bary: np.ndarray):
    """(albedo linear [N, 3], roughness [N], metallic [N]) at hits (triangle, barycentrics)."""
    n = len(tri)
    albedo, rough, metal = np.zeros((n, 3)), np.zeros(n), np.zeros(n)
    for k, mat in enumerate(mesh.materials):
        sel = mesh.face_material[tri] == k
        if not sel.any():
            continue
        t, b = tri[sel], bary[sel]
        a = np.broadcast_to(mat.base_color, (len(t), 3)).copy()
        if mat.base_color_texture is not None:
            srgb = _lookup(mesh, mat.base_color_texture, mat.base_color_sampling, t, b)
            a *= srgb_to_linear(torch.from_numpy(srgb)).numpy()
        if mesh.color is not None:  # base colour = factor x texture x COLOR_0 (glTF 2.0, 3.9.2)
            a *= _interpolate(mesh, mesh.color, t, b)
        r, m = np.full(len(t), mat.roughness), np.full(len(t), mat.metallic)
        if mat.metallic_roughness_texture is not None:
            mr = _lookup(mesh, mat.metallic_roughness_texture, mat.metallic_roughness_sampling, t, b)
            r, m = r * mr[:, 1], m * mr[:, 2]
        albedo[sel], rough[sel], metal[sel] = a, r, m
    return np.clip(albedo, 0, 1), np.clip(rough, 0, 1), np.clip(metal, 0, 1)


def face_normals(mesh: PBRMesh, tri: np.ndarray) -> np.ndarray:
    """Unnormalised geometric normals [N, 3] of triangles `tri`, counter-clockwise front (glTF)."""
    corners = mesh.vertices[mesh.faces[tri]]
    return np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


def drawn(mesh: PBRMesh, tri: np.ndarray, bary: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Which hits are drawn [N] bool: single-sided materials cull back faces (a face seen
    clockwise, glTF 2.0, 3.9.6), alpha MASK materials cut out alpha < alphaCutoff (3.9.4)."""
    keep = np.ones(len(tri), bool)
    back = (face_normals(mesh, tri) * dirs).sum(-1) > 0
    for k, mat in enumerate(mesh.materials):
        sel = mesh.face_material[tri] == k
        if not sel.any() or (mat.double_sided and not mat.cut_out):
            continue
        ok = np.ones(int(sel.sum()), bool) if mat.double_sided else ~back[sel]
        if mat.cut_out:
            ok &= coverage_alpha(mesh, mat, tri[sel], bary[sel]) >= mat.alpha_cutoff
        keep[sel] = ok
    return keep


def outside_brdf(mesh: PBRMesh, tri: np.ndarray) -> np.ndarray:
    """Hits [N] bool on materials the metallic-roughness BRDF cannot show (Material.outside_brdf)."""
    flagged = np.array([bool(m.outside_brdf) for m in mesh.materials])
    return flagged[mesh.face_material[tri]]


def shading_normals(mesh: PBRMesh, tri: np.ndarray, bary: np.ndarray,
                    dirs: np.ndarray) -> np.ndarray:
    """Interpolated vertex normals (face normal where missing), facing against `dirs`."""
    face_n = face_normals(mesh, tri)
    face_n /= np.maximum(np.linalg.norm(face_n, axis=-1, keepdims=True), 1e-20)
    vn = np.einsum("nk,nkc->nc", bary, mesh.normals[mesh.faces[tri]])
    length = np.linalg.norm(vn, axis=-1, keepdims=True)
    n = np.where(length > 1e-6, vn / np.maximum(length, 1e-20), face_n)
    flip = (n * dirs).sum(-1, keepdims=True) > 0
    return np.where(flip, -n, n)


def ray_intersector(tm):
    """trimesh's ray caster for the trimesh ``tm``: Embree (embreex) when it imports, else the
    pure-numpy one (slower, same answers up to float rounding). Every ray cast of gspi's
    meshes (this renderer, the export's texture bake and silhouette fit) takes it from here."""
    import trimesh

    try:
        from trimesh.ray.ray_pyembree import RayMeshIntersector
        return RayMeshIntersector(tm)
    except ImportError:
        return trimesh.ray.ray_triangle.RayMeshIntersector(tm)


class MeshTracer:
    """Closest hits of rays on a PBRMesh: (hit [N], t [N], triangle [N], barycentrics [N, 3])."""

    def __init__(self, mesh: PBRMesh):
        self.mesh = mesh
        self.intersector = ray_intersector(mesh.trimesh())

    def trace(self, origins: np.ndarray, dirs: np.ndarray):
        """Closest *drawn* hits (`drawn`): a culled or cut-out hit lets its ray go on from just
        past it, up to MAX_LAYERS surfaces deep."""
        n = len(origins)
        hit, t = np.zeros(n, bool), np.zeros(n)
        tri_all, bary_all = np.zeros(n, np.int64), np.zeros((n, 3))
        active, start, travelled = np.arange(n), origins.astype(np.float64).copy(), np.zeros(n)
        for _ in range(MAX_LAYERS):
            ids, tri, dist, bary = self._closest(start[active], dirs[active])
            ids = active[ids]
            keep = drawn(self.mesh, tri, bary, dirs[ids])
            done = ids[keep]
            hit[done], t[done] = True, travelled[done] + dist[keep]
            tri_all[done], bary_all[done] = tri[keep], bary[keep]
            active = ids[~keep]
            if not len(active):
                break
            step = dist[~keep] + LAYER_EPS
            start[active] += step[:, None] * dirs[active]
            travelled[active] += step
        return hit, t, tri_all, bary_all

    def _closest(self, origins: np.ndarray, dirs: np.ndarray):
        return closest_hits(self.intersector, self.mesh.vertices, self.mesh.faces, origins, dirs)


def closest_hits(intersector, vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray,
                 dirs: np.ndarray):
    """(ray ids hit, triangle, distance along the ray, barycentrics [n, 3]) of the first hits of
    unit rays on the mesh (vertices, faces) that ``intersector`` (``ray_intersector``) was built
    on. The one mesh ray cast of the project: this renderer and the MaterialAnything adapter's
    UV lookup (baselines/mesh_render.py) both take their visible surface from here."""
    import trimesh

    tri, ray, loc = intersector.intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
    dist = ((loc - origins[ray]) * dirs[ray]).sum(-1)
    bary = np.clip(trimesh.triangles.points_to_barycentric(vertices[faces[tri]], loc), 0, 1)
    bary /= np.maximum(bary.sum(-1, keepdims=True), 1e-12)
    return ray, tri, dist, bary


def outside_brdf_map(mesh: PBRMesh, tri: np.ndarray, hit: np.ndarray, n_sub: int, height: int,
                     width: int) -> np.ndarray | None:
    """[H, W] bool: pixels where any sub-sample hit a material outside the BRDF; None when the
    mesh has no such material (the view then writes no outside_brdf.png)."""
    if not any(m.outside_brdf for m in mesh.materials):
        return None
    flagged = hit[:n_sub] & outside_brdf(mesh, tri[:n_sub])
    return flagged.reshape(height * width, -1).any(-1).reshape(height, width)


def render_mesh_views(mesh: PBRMesh, cameras: list, height: int, width: int, *, env,
                      supersample: int) -> list[ViewRender]:
    """Render views of `mesh`; arguments and outputs as `gspi.data.procedural.render_view.render_views`."""
    tracer = MeshTracer(mesh)
    s2 = supersample * supersample
    out = []
    for K, w2c, seed in cameras:
        gen = torch.Generator().manual_seed(int(seed))
        sub = subpixel_rays(K, w2c, height, width, supersample, gen).reshape(-1, 3)
        centre = pixel_rays(K, w2c, height, width).reshape(-1, 3)
        dirs = torch.cat([sub, centre]).double().numpy()
        cam = np.linalg.inv(w2c)[:3, 3]
        hit, t, tri, bary = tracer.trace(np.broadcast_to(cam, dirs.shape).copy(), dirs)
        forward = np.asarray(w2c[2, :3], dtype=np.float64)
        z = t * (dirs @ forward)
        n_sub = len(sub)
        idx = np.nonzero(hit[:n_sub])[0]
        normal = shading_normals(mesh, tri[idx], bary[idx], dirs[idx])
        albedo, rough, metal = evaluate_materials(mesh, tri[idx], bary[idx])
        f32 = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
        rgb = split_sum(f32(albedo), f32(rough[:, None]), f32(metal[:, None]), f32(normal),
                        f32(-dirs[idx]), env)
        maps = _aggregate(height, width, s2, sub, centre, torch.from_numpy(hit[:n_sub]),
                          torch.from_numpy(hit[n_sub:]), f32(z[:n_sub]), f32(z[n_sub:]),
                          torch.from_numpy(idx), f32(normal),
                          (rgb, f32(albedo), f32(rough), f32(metal)))
        out.append(ViewRender(**maps, rays=len(dirs), sdf_evals=0,
                              outside_brdf=outside_brdf_map(mesh, tri, hit, n_sub, height, width)))
    return out
