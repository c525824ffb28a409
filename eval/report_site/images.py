"""Report thumbnails: display arrays -> small WebP files, error maps through a stated colour map.

Sizes: a thumbnail is at most `size` px on its long side, WebP at `quality` (Pillow); at the
defaults (128 px, 80) a material map or error map is 1-4 kB, which keeps a sweep of 20 scenes x
5 methods (4 views) well under 50 MB (docs/REPORT.md gives the measured numbers).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

ERROR_CMAP = "magma"


def to_uint8(image: np.ndarray) -> np.ndarray:
    """[H, W, 3] or [H, W] display values in [0, 1] (NaN -> 0) -> uint8."""
    arr = np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return (np.clip(arr, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)


def colorize_error(error: np.ndarray, vmax: float) -> np.ndarray:
    """[H, W] error -> [H, W, 3] in [0, 1] through ERROR_CMAP on [0, vmax] (clipped)."""
    from matplotlib import colormaps

    return colormaps[ERROR_CMAP](np.clip(error / vmax, 0.0, 1.0))[..., :3]


def css_gradient(steps: int = 9) -> str:
    """A CSS linear-gradient of ERROR_CMAP, for the colour bar on the page."""
    from matplotlib import colormaps

    cmap = colormaps[ERROR_CMAP]
    stops = [tuple(int(255 * v) for v in cmap(k / (steps - 1))[:3]) for k in range(steps)]
    return "linear-gradient(to right, " + ", ".join(f"rgb{s}" for s in stops) + ")"


def save_thumbnail(image: np.ndarray, path: Path, *, size: int = 128, quality: int = 80) -> Path:
    """Write `image` (display values in [0, 1]) as a WebP of long side <= `size`."""
    pil = Image.fromarray(to_uint8(image))
    scale = size / max(pil.size)
    if scale < 1:
        pil = pil.resize((max(1, round(pil.width * scale)), max(1, round(pil.height * scale))),
                         Image.LANCZOS)
    path.parent.mkdir(parents=True, exist_ok=True)
    pil.save(path, format="WEBP", quality=quality, method=4)
    return path


def envmap_preview(envmap: np.ndarray, cfg) -> np.ndarray:
    """Lat-long HDR map -> display values with the protocol's tone map (eval.protocol)."""
    import torch

    from eval.protocol import display_relit

    return display_relit(torch.from_numpy(np.ascontiguousarray(envmap)), cfg).numpy()
