"""Install-time fetch of one npm package, checked against its SHA-256 (the only network access).

`npm pack <spec>` from npm's registry into a folder; the tarball's SHA-256 must equal the one
the caller pins. Used by `gspi.data.pmndrs_assets` (Poly Haven HDRIs) and
`eval.report_site.model_viewer` (the report's 3D viewer). Failures raise `NpmUnavailable`
with one line.
"""
from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable


class NpmUnavailable(RuntimeError):
    """npm is missing, the download failed or the tarball does not match its checksum."""


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def npm_pack(spec: str, tarball: str, dest: Path, *, why: str) -> Path:
    """`npm pack <spec>` into `dest`; returns `dest / tarball`. `why` completes the error line."""
    npm = shutil.which("npm")
    if npm is None:
        raise NpmUnavailable(f"npm not found: cannot fetch {spec} ({why})")
    proc = subprocess.run([npm, "pack", spec, "--pack-destination", str(dest)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0 or not (dest / tarball).is_file():
        raise NpmUnavailable(f"`npm pack {spec}` failed (exit {proc.returncode}): {proc.stderr.strip()[-500:]}")
    return dest / tarball


def checked_tarball(path: Path, expected_sha256: str) -> bytes:
    """The tarball's bytes, refused unless their SHA-256 is `expected_sha256`."""
    data = Path(path).read_bytes()
    if sha256(data) != expected_sha256:
        raise NpmUnavailable(f"{path}: SHA-256 {sha256(data)} does not match {expected_sha256}")
    return data


def install_main(argv: list[str] | None, install: Callable[..., Path], description: str) -> int:
    """The install CLI of a vendored package: ``[--from-tgz FILE] [--force]``; prints the folder,
    or the one-line reason and exit 1."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--from-tgz", type=Path, default=None, help="use this npm tarball")
    p.add_argument("--force", action="store_true", help="unpack again")
    args = p.parse_args(argv)
    try:
        print(install(args.from_tgz, force=args.force))
    except NpmUnavailable as e:
        print(e, file=sys.stderr)
        return 1
    return 0
