"""`gspi-export asset=pbr_gs.ply out=asset.glb`: a PBR-GS asset as a textured glTF 2.0 mesh.

Steps (each its own module): the surface (``surface``: TSDF fusion of the lattice median-depth
renders + marching cubes, 2DGS's meshing), its UV atlas (``unwrap``: xatlas), the base-colour
and metallic-roughness textures baked from the surfels' PBR attributes (``bake``), the GLB
(``gltf_write``) and, optionally, a static preview image of the written file (``preview``).
What is lost on the way is listed in docs/EXPORT.md.

Bad inputs raise one ``StatedError`` naming the file and the problem: a missing file, an
unreadable PLY (``PlyFormatError``), an asset without surfels or without PBR attributes, one
that no lattice camera sees.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from eval.common.errors import MissingInputError, StatedError
from gspi.export.config import ExportConfig

log = logging.getLogger(__name__)


class ExportError(StatedError, ValueError):
    """An asset that cannot be exported; the message names the file and the problem."""

    def __init__(self, path: str | Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}")


def preview_path(glb: str | Path) -> Path:
    """``<dir>/<stem>_preview.png`` beside a GLB (what the report looks for)."""
    glb = Path(glb)
    return glb.with_name(f"{glb.stem}_preview.png")


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[P, 3] area-weighted unit vertex normals (trimesh)."""
    import trimesh

    return np.asarray(trimesh.Trimesh(vertices, faces, process=False, validate=False).vertex_normals)


def load_pbr_asset(path: Path):
    """The surfels of a PBR-GS PLY, refused (ExportError) without surfels or PBR attributes."""
    from gspi.gaussians.ply import read_ply

    if not path.is_file():
        raise MissingInputError(f"{path}: asset file not found (asset= takes GS-PI's pbr_gs.ply)")
    asset = read_ply(path)
    if asset.num_gaussians == 0:
        raise ExportError(path, "has no surfels")
    if not asset.has_pbr:
        raise ExportError(path, "has no PBR attributes (albedo_0..2, roughness, metallic): export GS-PI's "
                                "pbr_gs.ply, not a plain 2DGS asset")
    return asset


def export_asset(asset_path: str | Path, out: str | Path, cfg: ExportConfig | None = None) -> dict:
    """Export ``asset_path`` (a PBR-GS PLY) to the GLB ``out``; returns what was done and how long
    each step took (seconds)."""
    from eval.common.colorspace import linear_to_srgb
    from gspi.export.bake import bake_textures, texel_materials, texel_samples
    from gspi.export.gltf_write import write_glb
    from gspi.export.surface import asset_surface, face_normals, lattice_views
    from gspi.export.unwrap import unwrap

    import torch

    cfg = cfg or ExportConfig()
    asset_path, out = Path(asset_path), Path(out)
    clock = {}
    steps = 5 if cfg.preview else 4

    def step(k: int, what: str, seconds: float) -> None:  # one progress line per step
        log.info("[%d/%d] %s (%.1f s)", k, steps, what, seconds)

    start = t = time.perf_counter()
    asset = load_pbr_asset(asset_path)
    try:
        views = lattice_views(asset, image_size=cfg.mesh.image_size, alpha_threshold=cfg.mesh.alpha_threshold,
                              backend=cfg.backend)
        surface = asset_surface(views, asset.means.double().numpy(), cfg.mesh)
        clock["mesh_s"], t = time.perf_counter() - t, time.perf_counter()
        step(1, f"mesh: {surface.info['faces']} faces from {asset.num_gaussians} surfels", clock["mesh_s"])
        normals = vertex_normals(surface.vertices, surface.faces)
        uv_mesh = unwrap(surface.vertices, surface.faces, padding=cfg.texture.padding)
        clock["unwrap_s"], t = time.perf_counter() - t, time.perf_counter()
        step(2, f"UV atlas: {uv_mesh.charts} charts", clock["unwrap_s"])
        samples = texel_samples(uv_mesh.uv, uv_mesh.faces, uv_mesh.vertices, cfg.texture.size)
        if len(samples.index) == 0:
            raise ValueError("no texel centre falls inside the UV atlas (degenerate mesh or texture too small)")
        voxel = surface.info["voxel_size"]
        values = texel_materials(asset, samples, face_normals(uv_mesh.vertices, uv_mesh.faces)[samples.face], views,
                                 source=cfg.texture.source, neighbours=cfg.texture.neighbours, sigma_normal=voxel,
                                 tolerance=cfg.texture.depth_tolerance_voxels * voxel)
        maps = bake_textures(values, samples)
    except ValueError as exc:
        raise ExportError(asset_path, str(exc)) from exc
    clock["bake_s"], t = time.perf_counter() - t, time.perf_counter()
    step(3, f"textures: {len(samples.index)} texels baked at {cfg.texture.size}x{cfg.texture.size}", clock["bake_s"])
    albedo_srgb = linear_to_srgb(torch.from_numpy(maps["albedo"])).numpy()
    write_glb(out, uv_mesh.vertices, uv_mesh.faces, normals[uv_mesh.vertex_source], uv_mesh.uv,
              base_color_srgb=albedo_srgb, roughness=maps["roughness"], metallic=maps["metallic"])
    clock["write_s"], t = time.perf_counter() - t, time.perf_counter()
    step(4, f"wrote {out}", clock["write_s"])
    record = {"asset": str(asset_path), "glb": str(out), "surfels": asset.num_gaussians, "mesh": surface.info,
              "uv": {"charts": uv_mesh.charts, "atlas_size": list(uv_mesh.atlas_size),
                     "vertices": int(len(uv_mesh.vertices)), "texels_covered": int(len(samples.index))},
              "texture_size": cfg.texture.size, "bytes": out.stat().st_size}
    if cfg.preview:
        from gspi.export.preview import write_preview

        record["preview"] = str(write_preview(out, preview_path(out)))
        clock["preview_s"] = time.perf_counter() - t
        step(5, f"wrote {record['preview']}", clock["preview_s"])
    record["seconds"] = {**clock, "total_s": time.perf_counter() - start}
    log.info("%s -> %s: %d faces, %d charts, %dx%d textures, %.1f kB in %.1f s", asset_path, out,
             surface.info["faces"], uv_mesh.charts, cfg.texture.size, cfg.texture.size, record["bytes"] / 1e3,
             record["seconds"]["total_s"])
    return record
