"""A glTF quad with known textures and factors, written with trimesh (tests/test_data_glb.py and
tests/test_data_pathtrace.py): its GT maps are known block by block.
"""
from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")
Image = pytest.importorskip("PIL.Image")

# 8x8 texture, four constant 4x4 blocks (top-left, top-right, bottom-left, bottom-right).
BLOCKS = np.array([[[230, 20, 10], [10, 200, 40]], [[20, 30, 220], [250, 240, 30]]], np.uint8)
# metallicRoughness: G = roughness, B = metallic per block.
MR_BLOCKS = np.array([[[0, 51, 255], [0, 204, 0]], [[0, 102, 255], [0, 255, 128]]], np.uint8)
FACTOR = np.array([1.0, 128 / 255, 1.0])  # trimesh stores factors as 8-bit: keep them exact


def blocky(blocks: np.ndarray) -> np.ndarray:
    return np.repeat(np.repeat(blocks, 4, axis=0), 4, axis=1)


def quad_glb(path, *, textured=True):
    """A 2x2 double-sided quad in glTF's x-y plane facing +z (world -y), texture upright on it."""
    v = np.array([[-1, 1, 0], [1, 1, 0], [-1, -1, 0], [1, -1, 0]], float)
    m = trimesh.Trimesh(v, np.array([[0, 2, 1], [1, 2, 3]]), process=False)
    mat = trimesh.visual.material.PBRMaterial(
        baseColorFactor=np.append(FACTOR, 1.0), roughnessFactor=0.5, metallicFactor=1.0, doubleSided=True,
        baseColorTexture=Image.fromarray(blocky(BLOCKS)) if textured else None,
        metallicRoughnessTexture=Image.fromarray(blocky(MR_BLOCKS)) if textured else None)
    # trimesh's uv have v up and are flipped on export: (0, 1) here = glTF (0, 0), top-left.
    m.visual = trimesh.visual.TextureVisuals(uv=np.array([[0, 1], [1, 1], [0, 0], [1, 0.0]]),
                                             material=mat)
    path.write_bytes(m.export(file_type="glb"))
    return path
