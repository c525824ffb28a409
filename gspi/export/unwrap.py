"""UV atlas of a triangle mesh with xatlas (jpcy/xatlas through its PyPI binding, ``xatlas``).

xatlas cuts the mesh into charts, parametrises each and packs them into one atlas; vertices on
chart seams are duplicated (``vertex_source`` maps every output vertex to its input vertex).
The atlas's own size is xatlas's estimate; UVs are normalised to [0, 1] by it, in glTF's
convention (u along the image's columns, v down its rows from the top-left corner), so a
texture of any size is baked against them (``gspi.export.bake``), with the chart padding scaled
accordingly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class UVMesh:
    """vertices [P, 3], faces [F, 3], uv [P, 2] in [0, 1] (glTF convention) and, per output
    vertex, the index of the input vertex it copies (``vertex_source`` [P])."""

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    vertex_source: np.ndarray
    atlas_size: tuple[int, int]  # (width, height) of xatlas's packing, in its texels
    charts: int


def unwrap(vertices: np.ndarray, faces: np.ndarray, *, padding: int = 4) -> UVMesh:
    """One atlas for the whole mesh.

    Raises:
        ValueError: xatlas packed the charts into more than one atlas (cannot be one texture).
    """
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.uint32))
    pack = xatlas.PackOptions()
    pack.padding = int(padding)
    pack.bilinear = True
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count != 1:
        raise ValueError(f"xatlas packed the charts into {atlas.atlas_count} atlases; one texture needs one")
    vmapping, indices, uvs = atlas[0]
    return UVMesh(vertices=np.asarray(vertices, dtype=np.float64)[vmapping], faces=indices.astype(np.int64),
                  uv=uvs.astype(np.float64), vertex_source=vmapping.astype(np.int64),
                  atlas_size=(int(atlas.width), int(atlas.height)), charts=int(atlas.chart_count))
