"""The report's 3D viewer: Google's `<model-viewer>` web component, vendored at install time.

`install()` runs `npm pack @google/model-viewer@4.4.0` once (npm's registry; the only network
access), checks the tarball's SHA-256, and keeps its self-contained UMD bundle
(`dist/model-viewer-umd.min.js`, three.js included, a classic script, so a report opened from
the file system loads it; ES modules do not load from file://) and its Apache-2.0 LICENSE in
`<cache>/model-viewer-4.4.0/` (`<cache>` = $GSPI_CACHE, else ~/.cache/gspi). The report copies
them next to its pages; nothing is fetched when the report is viewed.

Why a vendored web component and not our own WebGL code: model-viewer is Google's maintained
glTF viewer (PBR metallic-roughness, image-based lighting from an equirectangular HDR, orbit
controls), which is what a relightable GLB needs to be turned and relit.

CLI (run by `make install`): `python -m eval.report_site.model_viewer [--from-tgz FILE] [--force]`.
"""
from __future__ import annotations

import sys
import tarfile
import tempfile
from pathlib import Path
from typing import Optional

from eval.lpips.weights import cache_dir
from eval.common.npm_package import NpmUnavailable, checked_tarball, install_main, npm_pack, sha256

PACKAGE = "@google/model-viewer@4.4.0"
TARBALL = "google-model-viewer-4.4.0.tgz"
SHA256 = "8b621bd58da86cfa9908aaedf5a263d49770d08fc9e04ca661e3019616565f02"
FOLDER = "model-viewer-4.4.0"
SCRIPT = "model-viewer-umd.min.js"
FILES = {SCRIPT: "package/dist/model-viewer-umd.min.js", "LICENSE": "package/LICENSE"}
SCRIPT_SHA256 = "d785423b1d046ea84a9f59ef6cf15f3077603e1bf938b01ced9b0240691884a2"


def root() -> Path:
    return cache_dir() / FOLDER


def installed_script() -> Optional[Path]:
    """The vendored bundle when installed and intact, else None (the report then says how)."""
    path = root() / SCRIPT
    if not path.is_file() or not (root() / "LICENSE").is_file():
        return None
    return path if sha256(path.read_bytes()) == SCRIPT_SHA256 else None


def install(tgz: Path | None = None, *, force: bool = False) -> Path:
    """Fetch (unless `tgz` is given), check and unpack the bundle; returns its folder."""
    if installed_script() is not None and not force:
        return root()
    with tempfile.TemporaryDirectory() as tmp:
        tgz = Path(tgz) if tgz is not None else npm_pack(PACKAGE, TARBALL, Path(tmp),
                                                           why="the report's 3D viewer")
        checked_tarball(tgz, SHA256)
        with tarfile.open(tgz) as tar:
            payload = {name: tar.extractfile(member).read() for name, member in FILES.items()}
    if sha256(payload[SCRIPT]) != SCRIPT_SHA256:
        raise NpmUnavailable(f"{tgz}: {FILES[SCRIPT]} has SHA-256 {sha256(payload[SCRIPT])}, not {SCRIPT_SHA256}")
    root().mkdir(parents=True, exist_ok=True)
    (root() / "LICENSE").write_bytes(payload["LICENSE"])
    (root() / SCRIPT).write_bytes(payload[SCRIPT])  # last: its checksum marks a finished install
    return root()


def main(argv: list[str] | None = None) -> int:
    return install_main(argv, install, __doc__.splitlines()[0])


if __name__ == "__main__":
    sys.exit(main())
