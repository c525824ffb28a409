"""Per-scene contact sheet PNG for eyes only (never scored).

`<scene>/contact_sheet.png`: one row per shown view (the first `num_views` test views, then
train views if the scene has fewer), columns

    rgb | albedo | roughness | metallic | normal | mask | relit_<env> ... (test views only)

rgb and relit images: clamp + sRGB; albedo as stored (sRGB); roughness/metallic grey;
normal as (n + 1) / 2. A bottom row shows the capture and relighting environments
(clamp + sRGB of the radiance scaled to mean 0.5). Tiles are upscaled by pixel repetition to
at least `min_tile` pixels.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from eval.common.colorspace import linear_to_srgb
from eval.common.imageio import read_exr, write_png
from eval.common.layout import Scene, read_view_file


def _srgb(x: np.ndarray) -> np.ndarray:
    return linear_to_srgb(torch.from_numpy(np.ascontiguousarray(x))).numpy()


def _rgb3(x: np.ndarray) -> np.ndarray:
    return np.repeat(x, 3, axis=-1) if x.shape[-1] == 1 else x


def _fit(tile: np.ndarray, h: int, w: int) -> np.ndarray:
    """Pad (black) or crop a tile to h x w."""
    out = np.zeros((h, w, 3), dtype=np.float32)
    th, tw = min(h, tile.shape[0]), min(w, tile.shape[1])
    out[:th, :tw] = tile[:th, :tw]
    return out


def _resize_nearest(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """Nearest-neighbour resize of an HxWx3 image to h x w."""
    rows = np.minimum((np.arange(h) + 0.5) * img.shape[0] / h, img.shape[0] - 1).astype(int)
    cols = np.minimum((np.arange(w) + 0.5) * img.shape[1] / w, img.shape[1] - 1).astype(int)
    return img[rows][:, cols]


def view_tiles(scene: Scene, split: str, view_id: str) -> list[np.ndarray]:
    """The tiles of one row (HxWx3 display values in [0, 1])."""
    vdir = scene.view_dir(split, view_id)
    tiles = [_srgb(read_view_file(vdir, "rgb.exr")), read_view_file(vdir, "albedo.png"),
             _rgb3(read_view_file(vdir, "roughness.png")), _rgb3(read_view_file(vdir, "metallic.png")),
             (read_view_file(vdir, "normal.exr") + 1.0) * 0.5 * read_view_file(vdir, "mask.png"),
             _rgb3(read_view_file(vdir, "mask.png"))]
    for env in scene.relight_envs:
        path = vdir / f"relit_{env}.exr"
        if path.is_file():
            tiles.append(_srgb(read_exr(path)))
    return tiles


def write_contact_sheet(scene: Scene, *, num_views: int = 3, min_tile: int = 128) -> Path:
    """Write `<scene>/contact_sheet.png` (see module docstring)."""
    shown = [("test", v.id) for v in scene.views.get("test", [])][:num_views]
    shown += [("train", v.id) for v in scene.views.get("train", [])][:num_views - len(shown)]
    rows = [view_tiles(scene, split, vid) for split, vid in shown]
    rep = max(1, -(-min_tile // max(scene.height, 1)))
    h, w = scene.height * rep, scene.width * rep
    ncols = max(len(r) for r in rows)
    envs = []
    for name in [scene.capture_env, *scene.relight_envs]:
        env = read_exr(scene.envmap_path(name))
        envs.append(_srgb(env * (0.5 / max(float(env.mean()), 1e-8))))
    grid = []
    for r in rows:
        tiles = [_fit(np.repeat(np.repeat(t, rep, 0), rep, 1), h, w) for t in r]
        tiles += [np.zeros((h, w, 3), np.float32)] * (ncols - len(tiles))
        grid.append(np.concatenate(tiles, axis=1))
    if envs:
        eh = max(8, min(scene.height * rep, (ncols * w) // (2 * len(envs))))
        strip = np.concatenate([_resize_nearest(e, eh, 2 * eh) for e in envs], axis=1)
        grid.append(_fit(strip, eh, ncols * w))
    path = scene.root / "contact_sheet.png"
    write_png(path, np.concatenate(grid, axis=0), bits=8)
    return path
