"""The canonical V = 32 Fibonacci hemisphere lattice of views and its cameras.

Paper, Sec. 3.2 ("Learned view-direction conditioning") and Experiments ("Data and PBR ground
truth"): Stage II conditions every point on a one-hot index of the view it was unprojected
from, so view k must be *the same physical viewing direction in every scene*. This module is
the single place that defines that lattice (method-notes.md, section 6):

    golden angle ga = pi (3 - sqrt 5)
    z_i   = z_min + (1 - z_min) (1 - (i + 0.5) / V)      (equal-area in z, Z-up world)
    phi_i = i * ga,  r_i = sqrt(1 - z_i^2)
    d_i   = (r_i cos phi_i, r_i sin phi_i, z_i)

Camera i sits at c_i = origin + radius * d_i and looks at the origin with a fixed field of view;
the pose depends only on (num_views, radius, min_elevation), never on the scene, and the
intrinsics only on (fov, image size). Camera convention: OpenCV (x right, y down, z forward),
`w2c` maps world -> camera, as in `eval.common.layout`.
"""
from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # 2.399963... rad
WORLD_UP = np.array([0.0, 0.0, 1.0])
# THE canonical lattice (keyword arguments of `lattice_cameras` less the image size). Every
# default elsewhere (gspi-data's `lattice:`, Stage I's config, the renderer) reads it from here;
# tests/test_lattice.py checks that the YAML files agree.
CANONICAL_LATTICE = MappingProxyType({"num_views": 32, "radius": 3.0, "fov_deg": 45.0,
                                      "min_elevation_deg": 0.0})
NUM_LATTICE_VIEWS = CANONICAL_LATTICE["num_views"]  # Stage II's one-hot width


def fibonacci_hemisphere_lattice(num_views: int = 32, *, min_elevation_deg: float = 0.0
                                 ) -> np.ndarray:
    """THE canonical view directions: a golden-angle spiral, equal-area in z on the upper hemisphere.

    Args:
        num_views: V, the number of views (the paper uses 32).
        min_elevation_deg: lowest elevation; z is equal-area in (sin(min_elevation), 1).
    Returns:
        [V, 3] float64 unit vectors (object centre -> camera), Z-up, all z > 0, in lattice
        order: index k of this array is view id f"{k:03d}" of every scene's train split.
    """
    if num_views < 1:
        raise ValueError(f"num_views must be >= 1, got {num_views}")
    if not 0.0 <= min_elevation_deg < 90.0:
        raise ValueError(f"min_elevation_deg must be in [0, 90), got {min_elevation_deg}")
    z_min = math.sin(math.radians(min_elevation_deg))
    i = np.arange(num_views, dtype=np.float64)
    z = z_min + (1.0 - z_min) * (1.0 - (i + 0.5) / num_views)
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * GOLDEN_ANGLE
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def look_at_w2c(center: np.ndarray, target: np.ndarray = np.zeros(3),
                up: np.ndarray = WORLD_UP) -> np.ndarray:
    """OpenCV world-to-camera matrix of a camera at `center` looking at `target`.

    forward f = normalize(target - center), right = normalize(f x up), down = f x right;
    c2w rotation columns = [right, down, f]; w2c = [R^T | -R^T c].

    Args:
        center, target, up: [3] world points / direction. `up` must not be parallel to f.
    Returns:
        [4, 4] float64 w2c.
    """
    center = np.asarray(center, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - center
    f = f / np.linalg.norm(f)
    right = np.cross(f, up)
    norm = np.linalg.norm(right)
    if norm < 1e-9:
        raise ValueError("look_at_w2c: viewing direction is parallel to the up vector")
    right = right / norm
    down = np.cross(f, right)
    R_c2w = np.stack([right, down, f], axis=1)
    w2c = np.eye(4)
    w2c[:3, :3] = R_c2w.T
    w2c[:3, 3] = -R_c2w.T @ center
    return w2c


def intrinsics_from_fov(fov_deg: float, width: int, height: int) -> np.ndarray:
    """[3, 3] pixel intrinsics with horizontal field of view `fov_deg`, square pixels,
    principal point at the image centre (pixel centres at +0.5, as `eval.views.pixel_rays`)."""
    focal = 0.5 * width / math.tan(0.5 * math.radians(fov_deg))
    return np.array([[focal, 0.0, 0.5 * width], [0.0, focal, 0.5 * height], [0.0, 0.0, 1.0]])


def cameras_from_directions(directions: np.ndarray, *, radius: float, fov_deg: float,
                            width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Cameras at `radius * d` looking at the origin.

    Args:
        directions: [N, 3] unit vectors origin -> camera.
    Returns:
        K [N, 3, 3] and w2c [N, 4, 4], float64, OpenCV.
    """
    K = intrinsics_from_fov(fov_deg, width, height)
    w2c = np.stack([look_at_w2c(radius * np.asarray(d, dtype=np.float64)) for d in directions])
    return np.repeat(K[None], len(w2c), axis=0), w2c


def lattice_cameras(*, num_views: int = CANONICAL_LATTICE["num_views"],
                    radius: float = CANONICAL_LATTICE["radius"],
                    fov_deg: float = CANONICAL_LATTICE["fov_deg"], width: int = 256, height: int = 256,
                    min_elevation_deg: float = CANONICAL_LATTICE["min_elevation_deg"]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The canonical cameras: identical for every scene (Stage II's one-hot index k <-> camera k).

    Returns:
        K [V, 3, 3], w2c [V, 4, 4] (float64, OpenCV), in lattice order.
    """
    dirs = fibonacci_hemisphere_lattice(num_views, min_elevation_deg=min_elevation_deg)
    return cameras_from_directions(dirs, radius=radius, fov_deg=fov_deg, width=width,
                                   height=height)


def held_out_directions(num_views: int, rng: np.random.Generator, *, lattice: np.ndarray,
                        min_elevation_deg: float = 10.0, max_elevation_deg: float = 70.0,
                        min_separation_deg: float = 6.0) -> np.ndarray:
    """Random viewing directions off the lattice (for the test/val splits).

    Azimuths are stratified in [0, 2 pi) with jitter, elevations uniform in the given band;
    a candidate closer than `min_separation_deg` to any lattice direction is redrawn.

    Args:
        rng: numpy Generator (seeded per scene by the caller).
        lattice: [V, 3] lattice directions to stay away from.
    Returns:
        [num_views, 3] float64 unit vectors, z > 0.
    """
    cos_sep = math.cos(math.radians(min_separation_deg))
    out = []
    for k in range(num_views):
        for _ in range(1000):
            az = 2.0 * math.pi * (k + rng.uniform()) / max(num_views, 1)
            el = math.radians(rng.uniform(min_elevation_deg, max_elevation_deg))
            d = np.array([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)])
            if len(lattice) == 0 or float(np.max(lattice @ d)) < cos_sep:
                break
        else:
            raise RuntimeError("held_out_directions: could not place a view off the lattice")
        out.append(d)
    return np.asarray(out, dtype=np.float64).reshape(num_views, 3)


def nearest_neighbour_angles(directions: np.ndarray) -> np.ndarray:
    """[N] angle (radians) from each unit direction to its nearest other direction."""
    cos = np.clip(directions @ directions.T, -1.0, 1.0)
    np.fill_diagonal(cos, -2.0)
    return np.arccos(np.clip(cos.max(axis=1), -1.0, 1.0))
