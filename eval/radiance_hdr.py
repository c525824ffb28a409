"""Radiance RGBE (`.hdr`) images: TensoIR ships its environment maps in this format.

Hand-written because no installed library reads it (Pillow does not; imageio needs the
FreeImage binary, OpenCV is not a dependency). Reads flat and new-style run-length encoded
scanlines (`-Y H +X W` orientation, the one every HDRI tool writes); writes flat scanlines,
which every reader accepts, mantissas rounded to nearest: an error below 2^-8 of the texel's
largest channel.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from eval.common.layout import LayoutError

MAGIC = (b"#?RADIANCE", b"#?RGBE")


def _header(data: bytes, path: Path) -> tuple[int, int, int]:
    """(height, width, offset of the pixels) from the text header."""
    if not data.startswith(MAGIC):
        raise LayoutError(f"{path}: not a Radiance .hdr file (no #?RADIANCE header)")
    end = data.find(b"\n\n")
    if end < 0:
        raise LayoutError(f"{path}: truncated .hdr header")
    if b"FORMAT=32-bit_rle_xyze" in data[:end]:
        raise LayoutError(f"{path}: XYZE .hdr files are not supported (RGBE only)")
    line_end = data.find(b"\n", end + 2)
    parts = data[end + 2:line_end].split()
    if len(parts) != 4 or parts[0] != b"-Y" or parts[2] != b"+X":
        raise LayoutError(f"{path}: unsupported .hdr resolution line {data[end + 2:line_end][:40]!r}")
    return int(parts[1]), int(parts[3]), line_end + 1


def _scanline(buf: memoryview, pos: int, width: int, path: Path) -> tuple[np.ndarray, int]:
    if width < 8 or width > 0x7FFF or buf[pos] != 2 or buf[pos + 1] != 2 or buf[pos + 2] & 0x80:
        return np.frombuffer(buf[pos:pos + 4 * width], np.uint8).reshape(width, 4), pos + 4 * width
    if (buf[pos + 2] << 8 | buf[pos + 3]) != width:
        raise LayoutError(f"{path}: run-length scanline width differs from the header")
    pos += 4
    out = np.empty((4, width), np.uint8)
    for ch in range(4):
        i = 0
        while i < width:
            count = buf[pos]
            if count > 128:
                out[ch, i:i + count - 128] = buf[pos + 1]
                i, pos = i + count - 128, pos + 2
            else:
                out[ch, i:i + count] = np.frombuffer(buf[pos + 1:pos + 1 + count], np.uint8)
                i, pos = i + count, pos + 1 + count
            if i > width:
                raise LayoutError(f"{path}: corrupt run-length data")
    return out.T, pos


def read_hdr(path: str | Path) -> np.ndarray:
    """[H, W, 3] float32 linear RGB of a Radiance .hdr file.

    Raises:
        LayoutError: naming the file (missing, not RGBE, truncated, corrupt).
    """
    path = Path(path)
    if not path.is_file():
        raise LayoutError(f"{path}: environment map not found")
    data = path.read_bytes()
    height, width, pos = _header(data, path)
    buf = memoryview(data)
    rows = []
    try:
        for _ in range(height):
            row, pos = _scanline(buf, pos, width, path)
            if row.shape[0] != width:
                raise IndexError
            rows.append(row)
    except IndexError as exc:
        raise LayoutError(f"{path}: truncated pixel data") from exc
    rgbe = np.stack(rows).astype(np.int32)
    scale = np.where(rgbe[..., 3] > 0, np.ldexp(1.0, rgbe[..., 3] - 136), 0.0)
    return (rgbe[..., :3] * scale[..., None]).astype(np.float32)


def write_hdr(path: str | Path, rgb: np.ndarray) -> Path:
    """Write [H, W, 3] linear RGB (negative values clamp to 0) as flat RGBE scanlines."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(encode_hdr(rgb))
    return path


def encode_hdr(rgb: np.ndarray) -> bytes:
    """The bytes of a Radiance .hdr file (flat RGBE scanlines) of [H, W, 3] linear RGB."""
    rgb = np.clip(np.asarray(rgb, np.float64), 0.0, None)
    peak = rgb.max(axis=-1)
    mant, expo = np.frexp(peak)  # peak = mant * 2^expo, mant in [0.5, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(peak > 1e-32, mant * 256.0 / np.where(peak > 0, peak, 1.0), 0.0)
    rgbe = np.zeros(rgb.shape[:2] + (4,), np.uint8)
    rgbe[..., :3] = np.clip(np.round(rgb * factor[..., None]), 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(peak > 1e-32, expo + 128, 0).astype(np.uint8)
    h, w = rgb.shape[:2]
    return b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode() + rgbe.tobytes()
