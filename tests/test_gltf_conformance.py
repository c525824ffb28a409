"""The Khronos conformance assets of ../shared/data/real-objects/feature-tests, imported as gspi
does: each asserts on the pixels (or values) that show the asset's "fail" mark when the
feature is not honoured. The same features are tested on small synthetic files in
tests/test_data_glb.py, which run wherever the shared assets are absent (`GSPI_REAL_OBJECTS`
names another copy)."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from gspi.data.gltf import Asset, read_gltf
from gspi.data.lattice import intrinsics_from_fov, look_at_w2c
from gspi.data.mesh_render import render_mesh_views, unit_frame_mesh

REAL_OBJECTS = Path(os.environ.get("GSPI_REAL_OBJECTS",
                                   Path(__file__).resolve().parents[2] / "shared" / "data" / "real-objects"))
FEATURES = REAL_OBJECTS / "feature-tests"
pytestmark = pytest.mark.skipif(not FEATURES.is_dir(), reason=f"{FEATURES} absent (set GSPI_REAL_OBJECTS)")


def front(mesh, size=256):
    """The assets' reference view: from glTF +z (world -y), up +z."""
    K = intrinsics_from_fov(40.0, size, size)
    return render_mesh_views(mesh, [(K, look_at_w2c(np.array([0.0, -3.0, 0.0])), 0)], size, size,
                             env=torch.ones(8, 16, 3), supersample=1)[0]


def test_alpha_blend_mode_test_cuts_each_panel_at_its_cutoff():
    """AlphaBlendModeTest: the MASK panels' alpha falls with height; a lower alphaCutoff keeps
    more of the panel (drawn opaque, each panel is whole: the fail mark)."""
    asset = read_gltf(FEATURES / "AlphaBlendModeTest.glb")
    frame = unit_frame_mesh(asset)

    def kept_fraction(name: str) -> float:
        prims = [p for p in asset.primitives if p.material.name == name]
        mesh = unit_frame_mesh(Asset(asset.path, prims, []))
        mesh.vertices = (np.concatenate([p.vertices for p in prims]) - frame.center) * frame.scale
        whole = dataclasses.replace(mesh, materials=[dataclasses.replace(m, alpha_mode="OPAQUE", double_sided=True)
                                                     for m in mesh.materials])
        return front(mesh).mask.sum() / front(whole).mask.sum()

    f25, f50, f75 = (kept_fraction(f"MatCutoff{c}") for c in ("25", "Default", "75"))
    assert kept_fraction("MatOpaque") == 1.0
    assert 0.9 > f25 > f50 + 0.05 > f75 + 0.1 > 0.15, (f25, f50, f75)
    blend = [p.material for p in asset.primitives if p.material.name == "MatBlend"][0]
    assert blend.outside_brdf == ("alphaMode BLEND",)
    r = front(frame)
    assert r.outside_brdf is not None and 0 < r.outside_brdf.sum() < r.mask.sum()


def test_texture_settings_test_culls_the_single_sided_quad():
    """TextureSettingsTest: a single-sided quad seen from behind hides a check mark behind a
    red cross; drawing its back face shows the red cross (the fail mark)."""
    r = front(unit_frame_mesh(read_gltf(FEATURES / "TextureSettingsTest.glb")))
    a = r.albedo_srgb
    red = (a[..., 0] > 0.6) & (a[..., 1] < 0.3) & (a[..., 2] < 0.3)
    green = (a[..., 1] > 0.5) & (a[..., 0] < 0.3) & (a[..., 2] < 0.3)
    assert red.sum() == 0 and green.sum() > 500


def test_simple_sparse_accessor_moves_the_listed_vertices():
    """SimpleSparseAccessor: 14 grid vertices; the sparse accessor lifts vertices 8, 10 and 12
    to heights 2, 3 and 4 (read without it, the top row is flat at height 1)."""
    v = read_gltf(FEATURES / "SimpleSparseAccessor" / "SimpleSparseAccessor.gltf").primitives[0].vertices
    np.testing.assert_allclose(v[7:, 2], [1, 2, 1, 3, 1, 4, 1])  # Z-up world: glTF y is z
    np.testing.assert_allclose(v[:7, 2], 0)
