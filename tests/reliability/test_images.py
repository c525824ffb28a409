"""Class 8, memory before checks (an image's size is read from its header before a pixel is
decoded), and the evaluator's file checks that already worked (kept as cases), plus class 10's
unreadable symlink and a mask too close to the border, which now name their file."""
from __future__ import annotations

import struct
import tracemalloc
import zlib

import numpy as np
import pytest

from tests.reliability.helpers import EVAL_FAST, assert_fails_naming, run_cli


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def write_huge_png(path, size: int = 12000) -> None:
    """A valid 1-bit grey PNG of size x size pixels, all black: about 20 KB on disk, hundreds
    of MB once decoded. Built by hand (zlib on the raw rows), no image library involved."""
    row = b"\x00" + bytes((size + 7) // 8)
    comp = zlib.compressobj(9)
    idat = b"".join(comp.compress(row) for _ in range(size)) + comp.flush()
    ihdr = struct.pack(">IIBBBBB", size, size, 1, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", idat)
                     + _png_chunk(b"IEND", b""))


def test_png_size_is_checked_from_the_header_before_decoding(tmp_path):
    from eval.common.imageio import ImageFormatError, read_png

    path = tmp_path / "albedo.png"
    write_huge_png(path)
    assert path.stat().st_size < 300_000
    tracemalloc.start()
    try:
        with pytest.raises(ImageFormatError, match=r"albedo.png: size 12000x12000 \(from the header\)"):
            read_png(path, channels=3, shape=(32, 32))
        with pytest.raises(ImageFormatError, match="more than"):
            _read_capped(path)  # no expected shape: the MAX_PIXELS cap, also from the header
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20 * 2**20, f"{peak / 2**20:.0f} MiB allocated before refusing"


def _read_capped(path):
    """read_png with a lowered MAX_PIXELS: the cap applies when no shape is expected."""
    import eval.common.imageio as imageio

    old = imageio.MAX_PIXELS
    imageio.MAX_PIXELS = 1000 * 1000
    try:
        return imageio.read_png(path, channels=1)
    finally:
        imageio.MAX_PIXELS = old


def test_gspi_eval_refuses_an_oversized_prediction_by_its_header(workspace):
    from eval.cli import main

    target = workspace / "pred" / "sphere_0" / "test" / "000" / "roughness.png"
    write_huge_png(target)
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, str(target), "12000x12000")


def test_exr_size_is_checked_from_the_header(tmp_path):
    from eval.common.imageio import ImageFormatError, read_exr, write_exr

    write_exr(tmp_path / "n.exr", np.zeros((8, 12, 3), np.float32))
    assert read_exr(tmp_path / "n.exr", shape=(8, 12)).shape == (8, 12, 3)
    with pytest.raises(ImageFormatError, match=r"n.exr: size 8x12"):
        read_exr(tmp_path / "n.exr", shape=(32, 32))


def test_gspi_eval_names_a_symlink_loop_instead_of_calling_it_not_modelled(workspace):
    """Before: an unreadable symlink counted as "channel not modelled" (exit 0)."""
    from eval.cli import main

    link = workspace / "pred" / "sphere_0" / "test" / "000" / "metallic.png"
    link.unlink()
    link.symlink_to(link)  # a loop
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, str(link), "symlink")


def test_gspi_eval_names_the_mask_too_close_to_the_border(workspace):
    """Before: "mask has no pixel at least 5 pixels away from the image border", no file named."""
    from eval.cli import main
    from eval.common.layout import write_view_file

    mask = np.zeros((32, 32), np.float32)
    mask[0:2, :] = 1.0
    vdir = workspace / "gt" / "sphere_0" / "test" / "000"
    write_view_file(vdir, "mask.png", mask)
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, str(vdir / "mask.png"), "border")


# Cases that already worked before the fix (the "exemplary" eval file checks).
BROKEN_FILES = {"truncated_png": lambda p: p.write_bytes(p.read_bytes()[:60]),
                "not_a_png": lambda p: p.write_text("hello"),
                "wrong_size": None, "grey_albedo": None}


@pytest.mark.parametrize("case", sorted(BROKEN_FILES))
def test_gspi_eval_names_a_broken_prediction_file(workspace, case):
    from eval.cli import main
    from eval.common.imageio import write_png

    vdir = workspace / "pred" / "sphere_0" / "test" / "001"
    target = vdir / ("albedo.png" if case == "grey_albedo" else "roughness.png")
    if case == "wrong_size":
        write_png(target, np.zeros((16, 16)), bits=16)
    elif case == "grey_albedo":
        write_png(target, np.zeros((32, 32)), bits=16)
    else:
        BROKEN_FILES[case](target)
    channels = ["eval.channels=[albedo]"] if case == "grey_albedo" else []
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST, *channels])
    assert_fails_naming(code, text, str(target))
