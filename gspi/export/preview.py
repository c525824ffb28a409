"""A static preview image of a GLB, drawn by gspi's own mesh renderer (no three.js, no browser).

The file is read back with gspi's glTF reader (``gspi.data.assets.gltf``), put in the importer's unit
frame and ray-cast at one camera (``gspi.data.assets.mesh_render``: Embree, 2 x 2 rays per pixel,
split-sum shading) under the procedural ``studio_softbox`` environment. Four panels side by
side: shaded (ACES tone map, sRGB), base colour (sRGB), roughness, metallic; white where the
mesh is not hit. What is shown is what the file holds: the textures as a glTF viewer reads them.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

PANEL_PX = 256
AZIMUTH_DEG, ELEVATION_DEG, FOV_DEG, DISTANCE = 35.0, 25.0, 40.0, 3.2  # unit-frame camera (radius-1 asset)
ENVIRONMENT = "studio_softbox"


def preview_camera(size: int) -> tuple[np.ndarray, np.ndarray]:
    """(K [3, 3], w2c [4, 4]) float64 looking at the unit frame's origin, world Z up."""
    from gspi.gaussians.cameras import intrinsics_from_fov, look_at

    az, el = math.radians(AZIMUTH_DEG), math.radians(ELEVATION_DEG)
    eye = torch.tensor([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)],
                       dtype=torch.float64) * DISTANCE
    w2c = look_at(eye, torch.zeros(3, dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    K = intrinsics_from_fov(math.radians(FOV_DEG), size, size, dtype=torch.float64)
    return K.numpy(), w2c.numpy()


def preview_panels(glb: str | Path, size: int = PANEL_PX) -> np.ndarray:
    """[size, 4 size, 3] uint8: shaded | base colour | roughness | metallic (module docstring)."""
    from eval.common.colorspace import tonemap
    from eval.relight import prefilter_environment
    from gspi.data.environments import make_environment
    from gspi.data.assets.gltf import read_gltf
    from gspi.data.assets.mesh_render import render_mesh_views, unit_frame_mesh

    mesh = unit_frame_mesh(read_gltf(glb))
    K, w2c = preview_camera(size)
    env = prefilter_environment(make_environment(ENVIRONMENT, 64))
    view = render_mesh_views(mesh, [(K, w2c, 0)], size, size, env=env, supersample=2)[0]
    hw = (size, size, -1)
    shaded = tonemap(torch.from_numpy(view.rgb.reshape(hw))).numpy()
    grey = lambda x: np.repeat(x.reshape(hw), 3, axis=-1)  # noqa: E731
    mask = view.mask.reshape(size, size, 1)
    panels = [np.where(mask, p, 1.0) for p in (shaded, view.albedo_srgb.reshape(hw), grey(view.roughness),
                                               grey(view.metallic))]
    return (np.clip(np.concatenate(panels, axis=1), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_preview(glb: str | Path, path: str | Path, size: int = PANEL_PX) -> Path:
    """Write ``preview_panels(glb)`` as a PNG at ``path``."""
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(preview_panels(glb, size)).save(path)
    return path
