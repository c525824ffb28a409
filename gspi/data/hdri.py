"""HDR environment files: the Poly Haven sets, a user's own files, and their convention.

Convention (docs/DATA.md, "Environment maps"): a file is an equirectangular (lat-long) map,
2:1, linear radiance, read exactly as `eval.envmap` reads every environment of the project,
i.e. Blender's layout for a Z-up world: row 0 is the zenith (+z), the bottom row the nadir,
the centre of the image looks along +x, a quarter of the width left of the centre along
+y, the left and right edges along -x. No rotation, no flip is applied: a Poly Haven file
lights a scene here exactly as it lights a Blender scene with the default world mapping.

Resolution: the map is area-averaged (`eval.envmap.downsample_latlong`, solid-angle
weighted) to the preset's `env_height` rows when that divides the file's rows, otherwise
resampled bilinearly at the texel centres after the largest exact area-average.
Exposure: as the procedural environments (`gspi.data.environments.normalise_exposure`): the
map is scaled so that a white Lambertian surface facing the brightest direction has radiance
`white_radiance` (1); the files' absolute units (their peaks range from 9 to 3e4) are not
kept, only the ratio between directions.

Sets (fixed, disjoint; named in docs/DATA.md): `POLYHAVEN_CAPTURE` (12, the input images'
lighting) and `POLYHAVEN_HELDOUT` (6, relighting ground truth only).

Negative values: the packaged 256 x 512 maps were downsized with a ringing filter, so every
one holds some negative texels (up to 2.5 % of them, next to bright lights); `read_hdri` sets
them to 0. NaN or Inf, a map that is not 2:1 RGB, or one black everywhere is an error naming
the file.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from eval.envmap import downsample_latlong, latlong_directions, sample_latlong
from eval.common.imageio import ImageFormatError, read_exr

POLYHAVEN_HELDOUT = ("city", "forest", "lobby", "studio", "sunset", "workshop")
POLYHAVEN_CAPTURE = ("apartment", "bridge", "dawn", "esplanade", "hall", "lab", "night",
                     "park", "sky", "sunrise", "venice", "warehouse")
POLYHAVEN_PREFIX = "ph_"   # scene.json names: "ph_city" (never clashes with procedural names)


class HDRIError(ImageFormatError):
    """An environment file has the wrong shape or invalid values."""


def read_hdri(path: str | Path) -> np.ndarray:
    """Read and check an environment file -> [H, 2H, 3] float32, finite, negatives set to 0."""
    path = Path(path)
    try:
        env = read_exr(path)  # raises naming the file on NaN/Inf or unreadable files
    except HDRIError:
        raise
    except ImageFormatError as e:
        raise HDRIError(str(e)) from e
    h, w, c = env.shape
    if c != 3 or w != 2 * h or h < 2:
        raise HDRIError(f"{path}: environment must be a 2:1 lat-long RGB map [H, 2H, 3], "
                        f"got {list(env.shape)}")
    env = np.maximum(env, 0.0)  # resampling ringing (see module docstring)
    if not (env > 0).any():
        raise HDRIError(f"{path}: environment is black everywhere")
    return env


def resample_hdri(env: Tensor, height: int) -> Tensor:
    """[H, 2H, 3] -> [height, 2 height, 3] (see module docstring)."""
    h = env.shape[0]
    if h == height:
        return env
    factor = max(f for f in range(1, h // max(height, 1) + 1) if h % f == 0 and
                 (h // f) >= height) if h > height else 1
    env = downsample_latlong(env, factor)
    if env.shape[0] == height:
        return env
    return sample_latlong(env, latlong_directions(height, 2 * height)).contiguous()


def load_hdri(path: str | Path, height: int, *, white_radiance: float = 1.0) -> Tensor:
    """Environment file -> [height, 2 height, 3] float32, exposure-normalised."""
    from gspi.data.environments import normalise_exposure

    env = torch.from_numpy(read_hdri(path))
    env = resample_hdri(env, height).float().contiguous()
    return normalise_exposure(env, white_radiance=white_radiance)


def polyhaven_path(name: str) -> Path:
    """The cached file of a Poly Haven HDRI ("city" or "ph_city"), installing on first use."""
    from gspi.data.pmndrs_assets import HDRI_NAMES, asset_path

    bare = name[len(POLYHAVEN_PREFIX):] if name.startswith(POLYHAVEN_PREFIX) else name
    if bare not in HDRI_NAMES:
        raise ValueError(f"unknown Poly Haven HDRI {name!r}; allowed: {', '.join(HDRI_NAMES)}")
    return asset_path(f"hdri/{bare}.exr")


def direction_of_pixel(row: float, col: float, height: int, width: int) -> np.ndarray:
    """Unit direction of (continuous) texel coordinates, texel centres at integers."""
    phi = math.pi / 2 - (row + 0.5) * math.pi / height
    theta = math.pi - (col + 0.5) * 2 * math.pi / width
    return np.array([math.cos(theta) * math.cos(phi), math.sin(theta) * math.cos(phi),
                     math.sin(phi)])
