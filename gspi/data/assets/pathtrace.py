"""Path-traced input views with Mitsuba 3 (`data.renderer=pathtraced`).

The split-sum input (`data.renderer=splitsum`, the default) has no shadows and no
interreflection; here the capture views are rendered by Mitsuba's `path` integrator
(`scalar_rgb` variant, CPU) with its `principled` BSDF driven by the same three parameters
(base colour = linear albedo, roughness, metallic; specular 0.5, i.e. F0 = 0.04 for
dielectrics), lit by the same capture environment as an `envmap` emitter oriented to the
project's lat-long convention (`ENV_TO_WORLD`), `hide_emitters` so misses stay black (the
layout's background), a box pixel filter (pixel averages, like the supersampled split-sum
input). Only rgb changes: GT maps, masks and the relighting protocol stay exact.

Geometry: a glTF asset goes in as it is (gspi.data.assets.mesh_render.PBRMesh: triangles, vertex
normals, UVs, its textures baked with their factors into linear bitmaps). A procedural SDF
scene is meshed with marching cubes (scikit-image) on a `mesh_resolution`^3 grid over
[-1.05, 1.05]^3, vertex normals are the SDF's exact gradient and the material is
evaluated per vertex (Mitsuba `mesh_attribute` textures, interpolated across triangles):
the mesh departs from the exact surface by a fraction of a voxel, and material patterns
finer than a voxel are blurred. Differences between the BSDFs are listed in docs/DATA.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

# Mitsuba's envmap looks up u = atan2(x, -z) / 2 pi, v = acos(y) / pi in its local frame
# (Y up, u = 0 along -Z); ours (eval.envmap): Z up, u = 0 along -x, u = 1/4 along +y. The
# rotation below maps Mitsuba's local -Z, +X, +Y to our -x, +y, +z.
ENV_TO_WORLD = [[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 0.0, 1.0]]
VARIANT = "scalar_rgb"  # the LLVM variants need a matching system LLVM; scalar always works


@dataclass(kw_only=True)
class PathTraceConfig:
    spp: int = 64                 # samples per pixel
    max_depth: int = 8            # path length (2 = direct light only)
    mesh_resolution: int = 160    # marching-cubes grid of SDF scenes


def _mitsuba():
    try:
        import mitsuba as mi
    except ImportError as e:
        raise ImportError("data.renderer=pathtraced needs Mitsuba 3: pip install mitsuba==3.9.1"
                          ) from e
    mi.set_variant(VARIANT)
    return mi


def _mesh(mi, name: str, vertices, faces, normals, bsdf, uv=None, attributes=None):
    import drjit as dr

    props = mi.Properties()
    props["bsdf"] = bsdf
    m = mi.Mesh(name, vertex_count=len(vertices), face_count=len(faces), props=props,
                has_vertex_normals=True, has_vertex_texcoords=uv is not None)
    p = mi.traverse(m)
    p["vertex_positions"] = dr.scalar.ArrayXf(np.asarray(vertices, np.float32).ravel())
    p["faces"] = dr.scalar.ArrayXu(np.asarray(faces, np.uint32).ravel())
    p["vertex_normals"] = dr.scalar.ArrayXf(np.asarray(normals, np.float32).ravel())
    if uv is not None:
        p["vertex_texcoords"] = dr.scalar.ArrayXf(np.asarray(uv, np.float32).ravel())
    p.update()
    for key, values in (attributes or {}).items():
        values = np.asarray(values, np.float32)
        m.add_attribute(key, 1 if values.ndim == 1 else values.shape[1],
                        dr.scalar.ArrayXf(values.ravel()))
    return m


def _bitmap(mi, values: np.ndarray) -> dict:
    arr = np.ascontiguousarray(values, dtype=np.float32)
    return {"type": "bitmap", "bitmap": mi.Bitmap(arr), "raw": True, "filter_type": "bilinear",
            "wrap_mode": "repeat"}


def sdf_mesh_parts(recipe: dict, resolution: int) -> list[dict]:
    """Marching-cubes mesh of a procedural scene with per-vertex material (one part)."""
    from skimage.measure import marching_cubes

    from gspi.data.procedural.materials import evaluate_material
    from gspi.data.procedural.sdf_shapes import ShapeSDF
    from gspi.data.procedural.sphere_trace import sdf_normals

    shape = ShapeSDF(recipe["shape"])
    lo, hi = -1.05, 1.05
    axis = torch.linspace(lo, hi, resolution)
    grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    with torch.no_grad():
        sdf = torch.cat([shape(grid[i:i + (1 << 18)]) for i in range(0, len(grid), 1 << 18)])
    vol = sdf.reshape(resolution, resolution, resolution).numpy()
    step = (hi - lo) / (resolution - 1)
    verts, faces, _, _ = marching_cubes(vol, level=0.0, spacing=(step, step, step))
    verts = torch.from_numpy((verts + lo).astype(np.float32))
    normals = sdf_normals(shape, verts).detach()
    mats = [evaluate_material(recipe["material"], shape.local(verts[i:i + (1 << 16)]))
            for i in range(0, len(verts), 1 << 16)]
    corners = verts[torch.from_numpy(faces.astype(np.int64))]
    face_n = torch.linalg.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    if float((face_n * normals[torch.from_numpy(faces[:, 0].astype(np.int64))]).sum()) < 0:
        faces = faces[:, ::-1]  # wind faces counter-clockwise around the outward normal
    return [{"vertices": verts.numpy(), "faces": np.ascontiguousarray(faces),
             "normals": normals.numpy(), "uv": None,
             "albedo": torch.cat([m.albedo_linear for m in mats]).numpy(),
             "roughness": torch.cat([m.roughness for m in mats]).numpy(),
             "metallic": torch.cat([m.metallic for m in mats]).numpy()}]


def glb_mesh_parts(mesh) -> list[dict]:
    """One part per material of a `gspi.data.assets.mesh_render.PBRMesh`, textures baked linear."""
    from eval.common.colorspace import srgb_to_linear

    corners = mesh.vertices[mesh.faces]
    face_n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_n /= np.maximum(np.linalg.norm(face_n, axis=-1, keepdims=True), 1e-20)
    parts = []
    for k, mat in enumerate(mesh.materials):
        faces = mesh.faces[mesh.face_material == k]
        if len(faces) == 0:
            continue
        # Flat-shaded primitives (no NORMAL): unshared vertices carrying their face normal.
        if np.linalg.norm(mesh.normals[faces], axis=-1).min() < 1e-6:
            f_idx = np.nonzero(mesh.face_material == k)[0]
            verts = mesh.vertices[faces].reshape(-1, 3)
            vn = mesh.normals[faces].reshape(-1, 3)
            missing = np.linalg.norm(vn, axis=-1) < 1e-6
            vn[missing] = np.repeat(face_n[f_idx], 3, axis=0)[missing]
            uv, faces = mesh.uv[faces].reshape(-1, 2), np.arange(3 * len(faces)).reshape(-1, 3)
        else:
            verts, vn, uv = mesh.vertices, mesh.normals, mesh.uv
        albedo = mat.base_color
        if mat.base_color_texture is not None:
            albedo = mat.base_color * srgb_to_linear(torch.from_numpy(
                mat.base_color_texture)).numpy()
        rough, metal = mat.roughness, mat.metallic
        if mat.metallic_roughness_texture is not None:
            rough = mat.roughness * mat.metallic_roughness_texture[..., 1]
            metal = mat.metallic * mat.metallic_roughness_texture[..., 2]
        parts.append({"vertices": verts, "faces": faces, "normals": vn, "uv": uv,
                      "albedo": albedo, "roughness": rough, "metallic": metal})
    return parts


def _bsdf(mi, part: dict, nverts: int) -> tuple:
    """principled BSDF of a part + the vertex attributes it reads."""
    attributes, params = {}, {}
    for key, mi_key in (("albedo", "base_color"), ("roughness", "roughness"),
                        ("metallic", "metallic")):
        value = np.asarray(part[key], dtype=np.float64)
        if value.ndim == 0 or (key == "albedo" and value.shape == (3,)):
            params[mi_key] = ({"type": "rgb", "value": value.tolist()} if key == "albedo"
                              else float(value))
        elif len(value) == nverts and value.ndim <= 2 and (value.ndim == 1 or
                                                           value.shape[1] == 3):
            attributes[f"vertex_{key}"] = np.clip(value, 0, 1)
            params[mi_key] = {"type": "mesh_attribute", "name": f"vertex_{key}"}
        else:  # a texture [h, w(, 3)]
            params[mi_key] = _bitmap(mi, np.clip(value, 0, 1))
    return mi.load_dict({"type": "principled", **params}), attributes


def mitsuba_scene(parts: list[dict], env: np.ndarray, cfg: PathTraceConfig, *,
                  hide_emitters: bool = True):
    """A Mitsuba scene of mesh parts lit by the lat-long `env` [h, w, 3] (our convention)."""
    mi = _mitsuba()
    scene = {"type": "scene",
             "integrator": {"type": "path", "max_depth": int(cfg.max_depth),
                            "hide_emitters": hide_emitters},
             "emitter": {"type": "envmap",
                         "bitmap": mi.Bitmap(np.ascontiguousarray(env, dtype=np.float32)),
                         "to_world": mi.ScalarTransform4f(ENV_TO_WORLD)}}
    for i, part in enumerate(parts):
        bsdf, attributes = _bsdf(mi, part, len(part["vertices"]))
        scene[f"part{i}"] = _mesh(mi, f"part{i}", part["vertices"], part["faces"],
                                  part["normals"], bsdf, uv=part["uv"], attributes=attributes)
    return mi.load_dict(scene)


def sensor(K: np.ndarray, w2c: np.ndarray, height: int, width: int, spp: int):
    """Mitsuba perspective sensor of an OpenCV camera (centred principal point, square px)."""
    mi = _mitsuba()
    if not (abs(K[0, 2] - width / 2) < 1e-6 and abs(K[1, 2] - height / 2) < 1e-6
            and abs(K[0, 0] - K[1, 1]) < 1e-6 * K[0, 0]):
        raise ValueError(f"pathtraced views need a centred principal point and square pixels, "
                         f"got K={K.tolist()}")
    R = np.asarray(w2c, dtype=np.float64)[:3, :3]
    origin = np.linalg.inv(w2c)[:3, 3]
    fov = math.degrees(2 * math.atan(0.5 * width / K[0, 0]))
    to_world = mi.ScalarTransform4f().look_at(origin=origin.tolist(),
                                              target=(origin + R[2]).tolist(),
                                              up=(-R[1]).tolist())
    return mi.load_dict({"type": "perspective", "fov": fov, "fov_axis": "x",
                         "near_clip": 1e-3, "to_world": to_world,
                         "film": {"type": "hdrfilm", "width": width, "height": height,
                                  "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                         "sampler": {"type": "independent", "sample_count": spp}})


def render_pathtraced(parts: list[dict], cameras: list, height: int, width: int,
                      env: np.ndarray, cfg: PathTraceConfig) -> list[np.ndarray]:
    """One [H, W, 3] float32 linear rgb per (K, w2c, seed) camera."""
    mi = _mitsuba()
    scene = mitsuba_scene(parts, env, cfg)
    out = []
    for K, w2c, seed in cameras:
        img = mi.render(scene, sensor=sensor(K, w2c, height, width, cfg.spp), spp=cfg.spp,
                        seed=int(seed) % (2**31))
        out.append(np.nan_to_num(np.array(img, dtype=np.float32)[..., :3], nan=0.0,
                                 posinf=0.0))
    return out


def retracer(renderer: str, options: dict | None, *, recipe: dict | None = None, mesh=None,
             key: str = "data.renderer"):
    """`generate_scene`'s `retrace` (or `relit_retrace`) for `data.renderer` (or
    `data.relit_renderer`, named by `key`); None for splitsum."""
    if renderer == "splitsum":
        return None
    if renderer != "pathtraced":
        raise ValueError(f"{key} must be splitsum or pathtraced, got {renderer!r}")
    cfg = PathTraceConfig(**dict(options or {}))
    _mitsuba()  # fail early when Mitsuba is missing

    def retrace(cameras, height, width, env):
        parts = (glb_mesh_parts(mesh) if mesh is not None else
                 sdf_mesh_parts(recipe, cfg.mesh_resolution))
        env_np = env.numpy() if isinstance(env, torch.Tensor) else np.asarray(env)
        return render_pathtraced(parts, cameras, height, width, env_np, cfg)
    return retrace
