"""Read and write 2DGS ``point_cloud.ply`` files (hbb1/2d-gaussian-splatting layout).

Layout (one ``vertex`` element, float32 properties, binary little endian), in the
official order (``GaussianModel.construct_list_of_attributes``)::

    x y z  nx ny nz  f_dc_0..2  f_rest_0..(3(K-1)-1)  opacity  scale_0 scale_1  rot_0..3

* ``nx ny nz`` are written as zeros by the official code and ignored on read.
* ``f_rest`` is channel-major: ``f_rest_0..K-2`` are the red coefficients 1..K-1,
  then green, then blue; K = (degree + 1)^2, so the count (0, 9, 24 or 45) gives
  the SH degree (0..3).
* Values are raw: log scales, inverse-sigmoid opacity, unnormalised quaternion
  (w, x, y, z) = rot_0..3.

GS-PI extension, the PBR-GS material attributes (written after ``rot_3`` when present,
all-or-none): ``albedo_0 albedo_1 albedo_2 roughness metallic``. Like ``opacity`` they are
stored raw, as inverse-sigmoid LOGITS: a reader gets the material as ``sigmoid(value)``, i.e.
base colour = sigmoid(albedo_0..2) in LINEAR RGB (not sRGB-encoded), perceptual roughness
(GGX alpha = roughness^2) = sigmoid(roughness), metalness = sigmoid(metallic), each in (0, 1).
Logits rather than activated values keep the round trip bit-exact (sigmoid followed by logit
is not) and match the 2DGS convention for ``opacity`` and ``scale_*``. Files with these
attributes carry header ``comment`` lines stating this (:data:`PBR_COMMENTS`).

Reading accepts any property order and any numeric type (cast to float32); float32
data round-trips bit-exactly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Union

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyParseError
from torch import Tensor

from eval.common.errors import StatedError
from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.sh import MAX_SH_DEGREE, num_sh_bases

PathLike = Union[str, Path]
POSITION = ("x", "y", "z")
NORMAL = ("nx", "ny", "nz")
F_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
SCALE = ("scale_0", "scale_1")
SCALE3 = ("scale_0", "scale_1", "scale_2")  # an official 3D Gaussian splatting file
ROT = ("rot_0", "rot_1", "rot_2", "rot_3")
PBR = ("albedo_0", "albedo_1", "albedo_2", "roughness", "metallic")
REQUIRED = POSITION + F_DC + ("opacity",) + SCALE + ROT
MAX_LOG_SCALE = 20.0  # exp(20) = 4.9e8 world units; float32 exp overflows at 88.7
PBR_COMMENTS = (
    "GS-PI PBR-GS: albedo_0..2 roughness metallic are logits; value = sigmoid(logit)",
    "GS-PI PBR-GS: albedo is linear RGB; roughness is perceptual (GGX alpha = roughness^2)",
)


class PlyFormatError(StatedError, ValueError):
    """A file is not a valid 2DGS point_cloud.ply; the message names file and problem."""

    def __init__(self, path: PathLike, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = str(path)
        self.problem = problem


def property_names(sh_degree: int, *, pbr: bool = False) -> list[str]:
    """Vertex property names in the official 2DGS order (+ GS-PI PBR logits)."""
    n_rest = 3 * (num_sh_bases(sh_degree) - 1)
    names = list(POSITION + NORMAL + F_DC) + [f"f_rest_{i}" for i in range(n_rest)]
    names += ["opacity", *SCALE, *ROT]
    return names + list(PBR) if pbr else names


def _load_vertices(path: PathLike) -> np.ndarray:
    try:
        # mmap="c": plyfile reads a binary element of scalar properties as one array from a mapped
        # file; mmap=False takes its per-value Python loop (1.9 s for a 6k-surfel asset).
        ply = PlyData.read(str(path), mmap="c")
    except FileNotFoundError:
        raise
    except (PlyParseError, ValueError, EOFError, UnicodeDecodeError, IndexError) as exc:
        raise PlyFormatError(path, f"not a readable PLY file ({type(exc).__name__}: {exc})") from exc
    if "vertex" not in [el.name for el in ply.elements]:
        raise PlyFormatError(path, "no 'vertex' element")
    data = ply["vertex"].data
    if data.dtype.names is None:
        raise PlyFormatError(path, "'vertex' element has no scalar properties")
    _check_no_trailing_data(path, ply)
    return np.array(data)  # a copy in memory: the file is not held open


def _check_no_trailing_data(path: PathLike, ply: PlyData) -> None:
    """A header declaring fewer vertices than the file holds would be read silently (plyfile
    stops at the declared count): compare the file's size with what the header declares."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)  # the header: plyfile has parsed it already, so it ends in here
    end = head.find(b"end_header")
    if end < 0 or b"\n" not in head[end:]:
        return
    header_bytes = head.index(b"\n", end) + 1
    body_bytes = Path(path).stat().st_size - header_bytes
    declared = sum(len(el.data) for el in ply.elements)
    if ply.text:
        body = Path(path).read_bytes()[header_bytes:]
        rows = len([line for line in body.splitlines() if line.strip()])
        extra = rows - declared
        unit = "data line(s)"
    else:
        if any(getattr(p, "len_dtype", None) for el in ply.elements for p in el.properties):
            return  # list properties: sizes vary per row, nothing simple to compare
        expected = sum(len(el.data) * el.data.dtype.itemsize for el in ply.elements)
        extra, unit = body_bytes - expected, "byte(s)"
    if extra > 0:
        raise PlyFormatError(path, f"{extra} {unit} after the {declared} element(s) the header declares "
                                   "(the header's vertex count is smaller than the file's)")


def _sh_rest_count(path: PathLike, names: set[str]) -> int:
    rest = sorted(int(n[len("f_rest_"):]) for n in names if n.startswith("f_rest_") and n[len("f_rest_"):].isdigit())
    if rest != list(range(len(rest))):
        raise PlyFormatError(path, f"f_rest properties are not numbered 0..{len(rest) - 1} without gaps")
    allowed = [3 * (num_sh_bases(d) - 1) for d in range(MAX_SH_DEGREE + 1)]
    if len(rest) not in allowed:
        raise PlyFormatError(path, f"{len(rest)} f_rest properties; expected one of {allowed} (SH degree 0..3)")
    return len(rest)


def _column(path: PathLike, data: np.ndarray, names: list[str]) -> np.ndarray:
    """[N, len(names)] float32 columns, checked finite."""
    if not names:
        return np.zeros((len(data), 0), dtype=np.float32)
    for name in names:
        if not np.issubdtype(data.dtype[name], np.number):
            raise PlyFormatError(path, f"property '{name}' is not numeric")
    out = np.stack([np.asarray(data[n]).astype(np.float32) for n in names], axis=1)
    bad = ~np.isfinite(out)
    if bad.any():
        rows, cols = np.nonzero(bad)
        first = f"first in property '{names[cols[0]]}' of vertex {rows[0]}"
        raise PlyFormatError(path, f"{int(bad.sum())} non-finite value(s) (NaN/Inf), {first}")
    return out


def read_ply(path: PathLike) -> Gaussians2D:
    """The surfels of a 2DGS point_cloud.ply, or of a 3DGS one flattened (``read_asset_ply``)."""
    return read_asset_ply(path)[0]


def read_asset_ply(path: PathLike) -> tuple[Gaussians2D, dict]:
    """(surfels, info) of a Gaussian PLY: 2DGS surfels as stored (info ``source_format: 2dgs``),
    or an official 3D Gaussian splatting file (detected by ``scale_2`` in its header) turned
    into surfels by ``gspi.gaussians.splat3d.flatten_3dgs`` (info says how, and is logged)."""
    data = _load_vertices(path)
    if "scale_2" in set(data.dtype.names):
        return _read_3dgs(path, data)
    return _read_2dgs(path, data), {"source_format": "2dgs", "path": str(path)}


def _read_3dgs(path: PathLike, data: np.ndarray) -> tuple[Gaussians2D, dict]:
    import logging

    from gspi.gaussians.splat3d import flatten_3dgs

    names = set(data.dtype.names)
    missing = [n for n in POSITION + F_DC + ("opacity",) + SCALE3 + ROT if n not in names]
    if missing:
        raise PlyFormatError(path, f"a 3D Gaussian splatting file (has scale_2) missing {missing}")
    surfels, info = flatten_3dgs(**_gaussian_columns(path, data, _sh_rest_count(path, names), SCALE3))
    info = {**info, "path": str(path), "dropped": dropped_3dgs_attributes(names)}
    log = logging.getLogger(__name__)
    log.warning("%s: a 3D Gaussian splatting file, %d Gaussians flattened to 2DGS surfels (%s; %.1f %% "
                "near-isotropic); dropped on reading: %s", path, len(data), info["rule"],
                100 * info["isotropic_fraction"], "; ".join(info["dropped"]))
    if len(data) and info["isotropic_fraction"] >= ALL_ISOTROPIC:
        log.warning("%s: %.0f %% of the 3D Gaussians are near-isotropic: their surfel normals are arbitrary",
                    path, 100 * info["isotropic_fraction"])
    return surfels, info


ALL_ISOTROPIC = 0.9  # a 3DGS file this isotropic has no surface orientation to flatten to (warned)


def dropped_3dgs_attributes(names: set[str]) -> list[str]:
    """What flattening a 3DGS file to surfels does not keep, one phrase each: always the third
    scale (the smallest axis becomes the surfel's normal), and PBR columns if present (a
    relightable 3DGS file: its materials are not read; Stage II predicts them)."""
    dropped = ["scale of each Gaussian's smallest axis (it becomes the surfel's normal)"]
    pbr = [n for n in PBR if n in names]
    if pbr:
        dropped.append(f"PBR attributes {', '.join(pbr)} (not read from a 3DGS file)")
    return dropped


def write_3dgs_ply(path: PathLike, means: Tensor, quats: Tensor, log_scales: Tensor, opacity_logits: Tensor,
                   sh_dc: Tensor, sh_rest: Tensor) -> None:
    """Writes 3D Gaussians in the official 3DGS layout (graphdeco-inria ``save_ply``):
    x y z nx ny nz f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3, float32, little endian."""
    n = len(means)
    cols = [means, torch.zeros(n, 3), sh_dc[:, 0, :], sh_rest.transpose(1, 2).reshape(n, 3 * sh_rest.shape[1]),
            opacity_logits[:, None], log_scales, quats]
    names = (list(POSITION) + list(NORMAL) + list(F_DC) + [f"f_rest_{i}" for i in range(3 * sh_rest.shape[1])]
             + ["opacity"] + list(SCALE3) + list(ROT))
    _write_vertices(path, names, torch.cat([c.detach().float().cpu() for c in cols], dim=1).numpy())


def _write_vertices(path: PathLike, names: list[str], values: np.ndarray, comments: list[str] = ()) -> None:
    """One float32 ``vertex`` element, binary little endian, columns ``values[:, i]`` named ``names[i]``."""
    records = np.empty(len(values), dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        records[name] = values[:, i]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    PlyData([PlyElement.describe(records, "vertex")], byte_order="<", comments=list(comments)).write(str(path))


def _read_2dgs(path: PathLike, data: np.ndarray) -> Gaussians2D:
    """Loads a 2DGS point_cloud.ply (official layout, optional GS-PI PBR logits).

    Args:
        path: file to read.

    Returns:
        :class:`Gaussians2D` with float32 CPU tensors of raw parameters.

    Raises:
        FileNotFoundError: if the file does not exist.
        PlyFormatError: if it is not a PLY, has no vertex element, lacks a required
            property, has a wrong number of f_rest properties, is truncated, or holds
            NaN/Inf values.
    """
    names = set(data.dtype.names)
    missing = [n for n in REQUIRED if n not in names]
    if missing:
        raise PlyFormatError(path, f"missing required vertex properties {missing} (neither a 2DGS nor a "
                                   "3DGS Gaussian file)")
    n_rest = _sh_rest_count(path, names)
    pbr_present = [n for n in PBR if n in names]
    if pbr_present and len(pbr_present) != len(PBR):
        raise PlyFormatError(path, f"incomplete PBR attributes: has {pbr_present}, needs all of {list(PBR)}")
    pbr = {}
    if pbr_present:
        values = torch.from_numpy(_column(path, data, list(PBR)))
        pbr = {"albedo_logits": values[:, :3].contiguous(), "roughness_logits": values[:, 3:4].contiguous(),
               "metallic_logits": values[:, 4:5].contiguous()}
    return Gaussians2D(**_gaussian_columns(path, data, n_rest, SCALE), **pbr)


def _gaussian_columns(path: PathLike, data: np.ndarray, n_rest: int, scale_names: tuple[str, ...]) -> dict:
    """The raw parameters a 2DGS and a 3DGS file share (``scale_names``: 2 or 3 log scales), as
    float32 tensors named as ``Gaussians2D``'s fields; a log scale that overflows is refused."""
    n = len(data)
    t = torch.from_numpy
    rest = _column(path, data, [f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, n_rest // 3)
    log_scales = _column(path, data, list(scale_names))
    if len(log_scales) and log_scales.max() > MAX_LOG_SCALE:
        row = int(np.argmax(log_scales.max(axis=1)))
        raise PlyFormatError(path, f"scale of vertex {row} is exp({log_scales[row].max():.3g}): overflows "
                                   f"(scale_* are LOG scales; above {MAX_LOG_SCALE} the surfel is larger than "
                                   "any scene)")
    return {"means": t(_column(path, data, list(POSITION))), "quats": t(_column(path, data, list(ROT))),
            "log_scales": t(log_scales), "opacity_logits": t(_column(path, data, ["opacity"])[:, 0].copy()),
            "sh_dc": t(_column(path, data, list(F_DC)))[:, None, :].contiguous(),
            "sh_rest": t(rest).transpose(1, 2).contiguous()}


def write_ply(path: PathLike, gaussians: Gaussians2D) -> None:
    """Writes surfels in the official 2DGS layout (binary little endian, float32).

    Normals are written as zeros like the official code; PBR logits are appended (with the
    header comments :data:`PBR_COMMENTS`) when ``gaussians.has_pbr``. Tensors are detached, moved to CPU and cast to float32.

    Args:
        path: output file (parent directories are created).
        gaussians: surfels to save.
    """
    g = gaussians.detach().to("cpu", torch.float32)
    n = g.num_gaussians
    cols = [g.means, torch.zeros(n, 3), g.sh_dc[:, 0, :], g.sh_rest.transpose(1, 2).reshape(n, 3 * g.sh_rest.shape[1]),
            g.opacity_logits[:, None], g.log_scales, g.quats]
    if g.has_pbr:
        cols += [g.albedo_logits, g.roughness_logits, g.metallic_logits]
    _write_vertices(path, property_names(g.sh_degree, pbr=g.has_pbr), torch.cat(cols, dim=1).numpy(),
                    list(PBR_COMMENTS) if g.has_pbr else [])
