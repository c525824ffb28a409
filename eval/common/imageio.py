"""Reading and writing the image files of the canonical layout (docs/FORMAT.md).

The only module of `eval/` that knows file formats: EXR through OpenEXR, PNG (8/16-bit)
through Pillow. Every reader returns float32 numpy arrays HxWxC (C = 1 or 3) and raises
`ImageFormatError` naming the file and the problem; nothing here returns a silent NaN.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
import png  # pypng

from eval.common.errors import StatedError


class ImageFormatError(StatedError, ValueError):
    """A file of the canonical layout is missing, unreadable or holds invalid values."""


# Largest image any reader decodes (a 16k x 16k frame); larger headers are refused before a
# pixel is decoded: a 280 KB PNG can declare 12000 x 12000 pixels (2 GB once decoded).
MAX_PIXELS = 16384 * 16384


def check_header_size(path: Path, width: int, height: int, shape: tuple[int, int] | None) -> None:
    """Refuses a header size other than ``shape`` (H, W) or above MAX_PIXELS, before decoding."""
    if shape is not None and (int(height), int(width)) != tuple(shape):
        raise ImageFormatError(f"{path}: size {height}x{width} (from the header) != expected "
                               f"{shape[0]}x{shape[1]}")
    if width * height > MAX_PIXELS:
        raise ImageFormatError(f"{path}: header declares {height}x{width} pixels, more than the "
                               f"{MAX_PIXELS} allowed")


def _existing_file(path: Path) -> None:
    """Absent, a broken or looping symlink, or a folder: an error naming the file and which."""
    if path.is_file():
        return
    if path.is_symlink():
        raise ImageFormatError(f"{path}: unreadable symlink (broken or a loop)")
    raise ImageFormatError(f"{path}: " + ("a folder, not a file" if path.is_dir() else "file not found"))


def _check_finite(arr: np.ndarray, path: Path) -> np.ndarray:
    bad = ~np.isfinite(arr)
    if bad.any():
        raise ImageFormatError(f"{path}: {int(bad.sum())} NaN/Inf values")
    return arr


def read_exr(path: str | Path, *, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read an EXR image as float32 HxWxC (C = 1 for a single channel, else 3 for R,G,B).

    Channel names accepted: R,G,B (RGB), Y or a single channel (grey). Values must be finite.
    ``shape`` (H, W), when given, is checked against the header before the pixels are read.
    """
    path = Path(path)
    _existing_file(path)
    try:
        with OpenEXR.File(str(path), header_only=True) as f:
            (x0, y0), (x1, y1) = f.header()["dataWindow"]
    except Exception as exc:  # OpenEXR raises plain exceptions for corrupt files
        raise ImageFormatError(f"{path}: not a readable EXR file ({exc})") from exc
    check_header_size(path, int(x1) - int(x0) + 1, int(y1) - int(y0) + 1, shape)
    try:
        with OpenEXR.File(str(path)) as f:
            channels = f.channels()
            names = list(channels.keys())
            if "RGB" in channels:
                arr = np.asarray(channels["RGB"].pixels, dtype=np.float32)
            elif "RGBA" in channels:
                arr = np.asarray(channels["RGBA"].pixels, dtype=np.float32)[..., :3]
            elif all(c in channels for c in "RGB"):
                arr = np.stack([np.asarray(channels[c].pixels, dtype=np.float32) for c in "RGB"], -1)
            elif len(names) == 1 or "Y" in channels:
                key = "Y" if "Y" in channels else names[0]
                arr = np.asarray(channels[key].pixels, dtype=np.float32)
            else:
                raise ImageFormatError(f"{path}: unsupported EXR channels {names}")
    except ImageFormatError:
        raise
    except Exception as exc:  # OpenEXR raises plain exceptions for corrupt files
        raise ImageFormatError(f"{path}: not a readable EXR file ({exc})") from exc
    if arr.ndim == 2:
        arr = arr[..., None]
    return _check_finite(np.ascontiguousarray(arr, dtype=np.float32), path)


def write_exr(path: str | Path, image: np.ndarray) -> None:
    """Write float32 HxWx3 (as RGB) or HxW / HxWx1 (as channel Y), ZIP-compressed, half=False."""
    path = Path(path)
    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim == 3 and arr.shape[-1] == 1:
        arr = arr[..., 0]
    _check_finite(arr, path)
    if arr.ndim == 3 and arr.shape[-1] == 3:
        channels = {"RGB": np.ascontiguousarray(arr)}
    elif arr.ndim == 2:
        channels = {"Y": np.ascontiguousarray(arr)}
    else:
        raise ImageFormatError(f"{path}: cannot write array of shape {arr.shape} as EXR")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    path.parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def read_png(path: str | Path, *, channels: int | None = None,
             shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read an 8- or 16-bit PNG as float32 HxWxC in [0, 1] (value / 255 or / 65535).

    Args:
        channels: 1 (grey) or 3 (RGB) to require; an alpha channel is dropped; a mismatch
            is an error naming the file (a grey map read as albedo would hide a wrong file).
        shape: (H, W) to require; checked against the header before any pixel is decoded
            (as is MAX_PIXELS), so an oversized file costs no memory.
    """
    path = Path(path)
    _existing_file(path)
    try:
        reader = png.Reader(filename=str(path))
        reader.preamble()
    except Exception as exc:  # pypng raises its own FormatError / ChunkError subclasses
        raise ImageFormatError(f"{path}: not a readable PNG file ({exc})") from exc
    check_header_size(path, reader.width, reader.height, shape)
    try:
        width, height, rows, info = reader.asDirect()
        planes, bitdepth = info["planes"], info["bitdepth"]
        arr = np.vstack([np.asarray(row, dtype=np.uint16) for row in rows])
    except Exception as exc:  # pypng raises its own FormatError / ChunkError subclasses
        raise ImageFormatError(f"{path}: not a readable PNG file ({exc})") from exc
    if bitdepth not in (1, 2, 4, 8, 16):
        raise ImageFormatError(f"{path}: unsupported PNG bit depth {bitdepth}")
    out = arr.reshape(height, width, planes).astype(np.float32) / float(2**bitdepth - 1)
    if planes in (2, 4):  # grey+alpha or RGBA: drop alpha
        out = out[..., :-1]
    if channels is not None and out.shape[-1] != channels:
        raise ImageFormatError(f"{path}: expected {channels} channel(s), found {out.shape[-1]}")
    return out


def write_png(path: str | Path, image: np.ndarray, *, bits: int = 8) -> None:
    """Write values in [0, 1] (clipped, rounded to nearest) as an 8- or 16-bit grey or RGB PNG.

    Pillow cannot write 16-bit RGB PNG, hence pypng.
    """
    path = Path(path)
    arr = np.asarray(image, dtype=np.float64)
    _check_finite(arr, path)
    if arr.ndim == 3 and arr.shape[-1] == 1:
        arr = arr[..., 0]
    if bits not in (8, 16):
        raise ValueError(f"bits must be 8 or 16, got {bits}")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[-1] == 3)):
        raise ImageFormatError(f"{path}: cannot write array of shape {arr.shape} as PNG")
    maxval = 2**bits - 1
    q = np.round(np.clip(arr, 0.0, 1.0) * maxval).astype(np.uint16 if bits == 16 else np.uint8)
    height, width = q.shape[:2]
    greyscale = q.ndim == 2
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = png.Writer(width, height, greyscale=greyscale, bitdepth=bits, compression=6)
    with open(path, "wb") as f:
        writer.write(f, q.reshape(height, -1))
