"""Write a textured PBR triangle mesh as one glTF 2.0 binary (``.glb``) with trimesh's exporter.

What the file holds (glTF 2.0, section 3.9 "Materials"):

* one mesh, one triangle primitive: POSITION, NORMAL (vertex normals), TEXCOORD_0, indices;
* one material, ``pbrMetallicRoughness`` with ``baseColorFactor`` 1, ``metallicFactor`` 1 and
  ``roughnessFactor`` 1 (factors are linear multipliers), ``baseColorTexture`` = the albedo
  sRGB-ENCODED (the spec's encoding of base colour textures), ``metallicRoughnessTexture`` =
  roughness in the GREEN channel and metallic in the BLUE channel, LINEAR (red unused, 0);
  both 8-bit RGB PNG; ``doubleSided`` true (the TSDF mesh is open where no lattice view saw it);
* axes: glTF is Y-up, the project's world is Z-up; positions and normals are written as
  (x, y, z) -> (x, z, -y), the inverse of the turn gspi's reader (``gspi.data.assets.gltf``) and
  Blender apply, so the asset comes back in its own frame.

trimesh keeps texture channels as given (checked by tests/test_export_glb.py) but stores UVs
with OpenGL's origin (bottom-left) and flips v on export, so the glTF-convention UVs are
handed to it as (u, 1 - v).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def to_u8(values: np.ndarray) -> np.ndarray:
    """Values in [0, 1] -> uint8, rounded to nearest."""
    return (np.clip(values, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def metallic_roughness_image(roughness: np.ndarray, metallic: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8 in glTF's packing: R unused (0), G roughness, B metallic (linear)."""
    return np.stack([np.zeros_like(roughness, dtype=np.uint8), to_u8(roughness), to_u8(metallic)], axis=-1)


def write_glb(path: str | Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, uv: np.ndarray, *,
              base_color_srgb: np.ndarray, roughness: np.ndarray, metallic: np.ndarray, name: str = "pbr_gs") -> Path:
    """Write the GLB (module docstring).

    Args:
        vertices: [P, 3] Z-up world. faces: [F, 3] counter-clockwise from outside.
        normals: [P, 3] unit vertex normals (Z-up). uv: [P, 2] glTF convention.
        base_color_srgb: [H, W, 3] sRGB-encoded albedo in [0, 1].
        roughness, metallic: [H, W] linear in [0, 1].
    """
    import trimesh
    from PIL import Image

    material = trimesh.visual.material.PBRMaterial(
        name=name, baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=1.0, roughnessFactor=1.0,
        baseColorTexture=Image.fromarray(to_u8(base_color_srgb), mode="RGB"),
        metallicRoughnessTexture=Image.fromarray(metallic_roughness_image(roughness, metallic), mode="RGB"),
        doubleSided=True)
    uv_gl = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])
    mesh = trimesh.Trimesh(vertices=vertices @ Z_UP_TO_Y_UP.T, faces=faces, vertex_normals=normals @ Z_UP_TO_Y_UP.T,
                           visual=trimesh.visual.TextureVisuals(uv=uv_gl, material=material),
                           process=False, validate=False)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = trimesh.exchange.gltf.export_glb(trimesh.Scene({name: mesh}), include_normals=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)
    return path
