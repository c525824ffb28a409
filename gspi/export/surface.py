"""The triangle surface of a 2DGS asset: TSDF fusion of its lattice depth renders (2DGS's method).

The asset is rasterized at the 32 canonical lattice cameras (``gspi.gaussians.lattice_render``,
the cameras every GS-PI asset is reconstructed and distilled at); each view's median depth
(2DGS's surface depth) where the rendered alpha exceeds ``alpha_threshold``, away from depth
edges (``tsdf.away_from_edges``), is fused into a TSDF
(``gspi.export.tsdf``) on a grid around the surfel centres, and its zero level set is the mesh.
Fragments below ``min_fragment`` of the faces (floaters: a few stray surfels' depths) are
dropped.

The median depth of a reconstructed asset lies about a pixel *behind* the object's surface (its
surfels form a shell a few layers thick, and the median is where their alpha reaches 0.5), while
its alpha covers the object's silhouette: so the zero level set alone is a mesh about a pixel
too small all round (docs/EXPORT.md measures it). Each of ``levels`` (TSDF levels outside the
zero set) is therefore extracted, ray-cast at the lattice cameras, and the one whose mask best
matches the asset's alpha mask there (mean IoU) is kept: the silhouette is fitted to the asset's
own renders, never to a ground truth. The lattice is a hemisphere: what no lattice view sees (an object's underside) is not
meshed, and the mesh is open there.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from gspi.export.config import MeshConfig
from gspi.export.tsdf import away_from_edges, compact, fuse_depths, grid_around, zero_surface
from gspi.gaussians.lattice_render import render_lattice_views
from gspi.gaussians.model import Gaussians2D


@dataclass
class SurfaceMesh:
    """Triangles in the asset's world frame (Z-up): vertices [P, 3] float64, faces [F, 3] int64
    counter-clockwise seen from outside, and how they were made (``info``)."""

    vertices: np.ndarray
    faces: np.ndarray
    info: dict


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[F, 3] unit normals of counter-clockwise faces (pointing outside)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-20)


@dataclass
class LatticeViews:
    """The asset at the lattice cameras: median depth [V, H, W], its validity [V, H, W] (alpha
    above the threshold), the material maps [V, H, W, 5] (blend-weight average of the surfels'
    linear albedo RGB, roughness, metallic; 0 where not valid) and the cameras."""

    depth: np.ndarray
    valid: np.ndarray
    materials: np.ndarray
    K: np.ndarray
    w2c: np.ndarray


@torch.no_grad()
def lattice_views(asset: Gaussians2D, *, image_size: int, alpha_threshold: float,
                  backend: str = "auto") -> LatticeViews:
    """The asset rendered at the lattice cameras, valid where its alpha > ``alpha_threshold``."""
    out = render_lattice_views(asset.detach(), image_size=image_size, backend=backend, with_pbr=True)
    alpha = out.alpha.float()
    depth = out.depth_median[..., 0].float().numpy()
    valid = (alpha[..., 0].numpy() > alpha_threshold) & (depth > 0)
    materials = (out.features.float() / alpha.clamp_min(1e-12)).numpy() * valid[..., None]
    return LatticeViews(depth=depth, valid=valid, materials=materials.astype(np.float32),
                        K=out.meta["Ks"].double().numpy(), w2c=out.meta["viewmats"].double().numpy())


def drop_fragments(vertices: np.ndarray, faces: np.ndarray, min_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep the connected components (shared vertices) holding at least ``min_fraction`` of the
    faces (the largest always); unused vertices are removed and faces renumbered."""
    import trimesh

    labels = trimesh.graph.connected_component_labels(trimesh.graph.face_adjacency(faces), node_count=len(faces))
    counts = np.bincount(labels)
    keep_labels = (counts >= min_fraction * len(faces)) | (counts == counts.max())
    return compact(vertices, faces[keep_labels[labels]])


SILHOUETTE_STRIDE = 2  # the silhouette fit casts every 2nd pixel's ray (a quarter of the pixels)


def strided_rays(K: np.ndarray, w2c: np.ndarray, height: int, width: int,
                 stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(camera centres [V, 3], unit directions [V, ceil(H / stride), ceil(W / stride), 3]) of
    every ``stride``-th pixel's centre ray (``gspi.gaussians.cameras.pixel_rays``, OpenCV
    cameras ``K``, ``w2c``)."""
    from gspi.gaussians.cameras import camera_centers, pixel_rays

    K, w2c = torch.as_tensor(K, dtype=torch.float64), torch.as_tensor(w2c, dtype=torch.float64)
    return camera_centers(w2c).numpy(), pixel_rays(K, w2c, height, width)[:, ::stride, ::stride].numpy()


def mesh_masks(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, w2c: np.ndarray,
               height: int, width: int, stride: int = 1,
               rays: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """[V, ceil(H / stride), ceil(W / stride)] bool: pixels (every ``stride``-th row and column)
    whose centre ray (``strided_rays``; ``rays``: its result for these cameras, when the
    caller casts them at several meshes) meets the mesh."""
    import trimesh

    from gspi.data.assets.mesh_render import ray_intersector

    caster = ray_intersector(trimesh.Trimesh(vertices, faces, process=False))
    centres, dirs = strided_rays(K, w2c, height, width, stride) if rays is None else rays
    out = np.zeros(dirs.shape[:3], dtype=bool)
    for v in range(len(dirs)):
        d = np.ascontiguousarray(dirs[v].reshape(-1, 3))
        out[v] = caster.intersects_any(np.broadcast_to(centres[v], d.shape).copy(), d).reshape(out.shape[1:])
    return out


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Mean over views of |a & b| / |a | b| ([V, H, W] bool; a view where both are empty counts 1)."""
    inter, union = (a & b).sum(axis=(1, 2)), (a | b).sum(axis=(1, 2))
    return float(np.mean(np.where(union > 0, inter / np.maximum(union, 1), 1.0)))


def asset_surface(views: LatticeViews, centres: np.ndarray, cfg: MeshConfig) -> SurfaceMesh:
    """The mesh (module docstring) of the asset seen in ``views``, on a grid around its surfel
    ``centres`` [N, 3].

    Raises:
        ValueError: no lattice pixel shows the asset (no surfel in view), or the fused depth has
            no surface.
    """
    seen = int(views.valid.sum())
    if seen == 0:
        raise ValueError(f"no surfel in view: none of the {len(views.depth)} lattice cameras shows the asset with "
                         f"alpha > {cfg.alpha_threshold} (empty, transparent, or not in the lattice's frame: "
                         "radius-3 cameras looking at the origin)")
    grid = grid_around(centres, resolution=cfg.resolution, margin=cfg.margin)
    truncation = cfg.truncation_voxels * grid.voxel_size
    valid = away_from_edges(views.depth, views.valid, truncation)
    tsdf, weight = fuse_depths(grid, views.depth, valid, views.K, views.w2c, truncation=truncation)
    height, width = views.valid.shape[1:]
    s = SILHOUETTE_STRIDE
    candidates, ious = [], []
    rays = strided_rays(views.K, views.w2c, height, width, s) if len(cfg.levels) > 1 else None
    for level in cfg.levels:
        vertices, faces = zero_surface(tsdf, weight, grid, level=level)
        n_raw = len(faces)
        vertices, faces = drop_fragments(vertices, faces, cfg.min_fragment)
        candidates.append((vertices, faces, n_raw))
        ious.append(mask_iou(mesh_masks(vertices, faces, views.K, views.w2c, height, width, s, rays),
                             views.valid[:, ::s, ::s]) if len(cfg.levels) > 1 else float("nan"))
    best = int(np.nanargmax(ious)) if len(cfg.levels) > 1 else 0
    vertices, faces, n_raw = candidates[best]
    info = {"method": "tsdf_lattice_median_depth", "views": len(views.depth), "image_size": cfg.image_size,
            "valid_pixels": seen, "grid_shape": list(grid.shape), "voxel_size": grid.voxel_size,
            "level": float(cfg.levels[best]), "silhouette_iou": {str(lv): round(x, 5) for lv, x in zip(cfg.levels, ious)},
            "faces_marching_cubes": n_raw, "faces": int(len(faces)), "vertices": int(len(vertices))}
    return SurfaceMesh(vertices=vertices, faces=faces, info=info)
