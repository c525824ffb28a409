"""Read a glTF 2.0 asset (`.glb`, or `.gltf` with its buffers) as triangles with PBR materials.

Why not trimesh's loader: it stores `baseColorFactor` as 8-bit colour and flips texture
rows; ground-truth albedo needs the factors and texture lookups exactly as the glTF spec
defines them, so this module reads the (small) subset of the format the benchmark needs
with numpy, and trimesh is used for what it does well, ray casting (gspi.data.assets.mesh_render).

Read: the default scene's node tree (matrix or TRS per node), every triangle primitive
(mode 4) with POSITION, NORMAL, TEXCOORD_0/1, COLOR_0 and indices (any component type,
strides, normalised integers, sparse accessors), and its material's `pbrMetallicRoughness`:

    albedo (linear)  = baseColorFactor.rgb * srgb_to_linear(baseColorTexture.rgb) * COLOR_0.rgb
    roughness        = roughnessFactor * metallicRoughnessTexture.G   (linear)
    metallic         = metallicFactor  * metallicRoughnessTexture.B   (linear)
    alpha            = baseColorFactor.a * baseColorTexture.a * COLOR_0.a   (MASK materials)

Textures are sampled bilinearly at their UV set after KHR_texture_transform, wrapped as their
sampler says, glTF's texel convention (uv (0, 0) = the top-left corner of the image's first
row); `alphaMode`, `alphaCutoff` and `doubleSided` are kept for the renderer
(gspi.data.assets.mesh_render: cut-outs, culling). Axes: glTF is Y-up; positions and normals are
turned to the project's Z-up world as Blender's importer does, (x, y, z) -> (x, -z, y).

Not read, and what happens instead (stated, logged, recorded in scene.json):
* no material, or a material without `pbrMetallicRoughness`: the spec's defaults (base colour
  1, metallic 1, roughness 1);
* textures whose UV set the primitive lacks: factor-only material;
* normal, occlusion and emissive textures, texture samplers' filters, extensions in
  `extensionsUsed` other than Draco and texture transform: ignored;
* alphaMode BLEND and KHR_materials_* (transmission, clearcoat, sheen, ...): drawn as opaque
  metallic-roughness, listed in `Material.outside_brdf` (each view's outside_brdf.png);
* KHR_draco_mesh_compression is decoded with DracoPy;
* any other extension in `extensionsRequired` (meshopt, KTX2), a non-triangle primitive, a
  truncated or malformed file: `GLTFError` naming the file.
"""
from __future__ import annotations

import base64
import io
import json
import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from eval.common.errors import StatedError

log = logging.getLogger(__name__)

GLB_MAGIC = b"glTF"
COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
              5126: np.float32}
NORMALISED = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}
WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
DRACO = "KHR_draco_mesh_compression"  # decoded with DracoPy (the package's bunny and suzi)
TEXTURE_TRANSFORM = "KHR_texture_transform"
SUPPORTED_EXTENSIONS = (DRACO, TEXTURE_TRANSFORM)
REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648  # sampler wrapS / wrapT
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


class GLTFError(StatedError, ValueError):
    """A glTF file is malformed, truncated or uses something this reader cannot honour."""


@dataclass(frozen=True)
class TextureSampling:
    """How a material texture is looked up: which UV set (``texCoord``), the
    KHR_texture_transform matrix (uv' = M [u, v, 1], M = T R S; identity without it) and the
    sampler's wrap modes (glTF enums; REPEAT by default)."""

    texcoord: int = 0
    matrix: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))  # the top 2 x 3 of M
    wrap_s: int = REPEAT
    wrap_t: int = REPEAT

    def apply(self, uv: np.ndarray) -> np.ndarray:
        m = np.asarray(self.matrix, dtype=np.float64)
        return uv @ m[:, :2].T + m[:, 2]


def texture_transform_matrix(ext: dict) -> tuple:
    """KHR_texture_transform's ``offset``, ``rotation`` (radians), ``scale`` -> (T R S)[:2]."""
    (ox, oy), rot, (sx, sy) = ext.get("offset", [0, 0]), float(ext.get("rotation", 0.0)), ext.get("scale", [1, 1])
    c, s = np.cos(rot), np.sin(rot)
    m = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1]]) @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) \
        @ np.diag([sx, sy, 1.0])
    return tuple(map(tuple, m[:2].tolist()))


@dataclass
class Material:
    """Factors (linear) and optional textures: base colour sRGB [h, w, 3] in [0, 1] and
    metallic-roughness [h, w, 3] (G roughness, B metallic) in [0, 1]."""

    base_color: np.ndarray = field(default_factory=lambda: np.ones(3))
    roughness: float = 1.0
    metallic: float = 1.0
    base_color_texture: np.ndarray | None = None
    metallic_roughness_texture: np.ndarray | None = None
    name: str = ""
    base_color_sampling: TextureSampling = field(default_factory=TextureSampling)
    metallic_roughness_sampling: TextureSampling = field(default_factory=TextureSampling)
    # Coverage (glTF 2.0, 3.9.4): alpha = baseColorFactor.a x baseColorTexture.a x COLOR_0.a; MASK
    # draws a hit only where alpha >= alpha_cutoff. OPAQUE ignores alpha; BLEND is drawn opaque
    # and flagged in `outside_brdf`. The alpha texture is kept only for MASK materials.
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    base_alpha: float = 1.0
    base_color_alpha_texture: np.ndarray | None = None  # [h, w] in [0, 1], base colour's sampling
    double_sided: bool = False  # single-sided: hits on back faces (clockwise seen) are culled
    outside_brdf: tuple[str, ...] = ()  # what the metallic-roughness BRDF cannot show (BLEND, KHR_*)

    @property
    def cut_out(self) -> bool:
        return self.alpha_mode == "MASK"


@dataclass
class Primitive:
    """World (Z-up) triangles: vertices [V, 3], faces [F, 3], normals [V, 3] or None,
    uv [V, 2] (glTF convention) or None."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None
    material: Material
    uv1: np.ndarray | None = None      # TEXCOORD_1 [V, 2]
    color: np.ndarray | None = None    # COLOR_0 RGB [V, 3], linear (multiplies the base colour)
    alpha: np.ndarray | None = None    # COLOR_0's alpha [V] where COLOR_0 is VEC4 (multiplies alpha)


@dataclass
class Asset:
    path: Path
    primitives: list[Primitive]
    ignored: list[str]          # what was not honoured (module docstring), for scene.json


def _split_glb(path: Path, data: bytes) -> tuple[dict, bytes | None]:
    if len(data) < 20:
        raise GLTFError(f"{path}: truncated GLB ({len(data)} bytes)")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != GLB_MAGIC or version != 2:
        raise GLTFError(f"{path}: not a glTF 2.0 binary (magic {magic!r}, version {version})")
    if length > len(data):
        raise GLTFError(f"{path}: truncated GLB (header says {length} bytes, file has "
                        f"{len(data)})")
    chunks, offset = {}, 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<I4s", data, offset)
        if offset + 8 + size > length:
            raise GLTFError(f"{path}: truncated GLB chunk {kind!r}")
        chunks.setdefault(kind, data[offset + 8:offset + 8 + size])
        offset += 8 + size
    if b"JSON" not in chunks:
        raise GLTFError(f"{path}: GLB has no JSON chunk")
    try:
        gltf = json.loads(chunks[b"JSON"].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise GLTFError(f"{path}: GLB JSON chunk is malformed ({e})") from e
    return gltf, chunks.get(b"BIN\x00")


class _Reader:
    def __init__(self, path: Path):
        self.path = path
        data = path.read_bytes()
        if path.suffix.lower() == ".glb" or data[:4] == GLB_MAGIC:
            self.gltf, self.bin = _split_glb(path, data)
        else:
            try:
                self.gltf, self.bin = json.loads(data.decode("utf-8")), None
            except (UnicodeDecodeError, json.JSONDecodeError) as e:
                raise GLTFError(f"{path}: not a glTF JSON file ({e})") from e
        if not str(self.gltf.get("asset", {}).get("version", "")).startswith("2"):
            raise GLTFError(f"{path}: not glTF 2.0 (asset.version "
                            f"{self.gltf.get('asset', {}).get('version')!r})")
        self._buffers: dict[int, bytes] = {}

    def fail(self, msg: str) -> GLTFError:
        return GLTFError(f"{self.path}: {msg}")

    def _get(self, key: str, index: int) -> dict:
        items = self.gltf.get(key, [])
        if not 0 <= index < len(items):
            raise self.fail(f"{key}[{index}] does not exist")
        return items[index]

    def buffer(self, index: int) -> bytes:
        if index not in self._buffers:
            buf = self._get("buffers", index)
            uri = buf.get("uri")
            if uri is None:
                data = self.bin
                if data is None:
                    raise self.fail(f"buffers[{index}] has no uri and the file no BIN chunk")
            elif uri.startswith("data:"):
                data = base64.b64decode(uri.split(",", 1)[1])
            else:
                file = self.path.parent / uri
                if not file.is_file():
                    raise self.fail(f"buffer file {file} not found")
                data = file.read_bytes()
            if len(data) < buf.get("byteLength", 0):
                raise self.fail(f"buffers[{index}] truncated ({len(data)} of "
                                f"{buf['byteLength']} bytes)")
            self._buffers[index] = data
        return self._buffers[index]

    def view_bytes(self, index: int) -> tuple[bytes, int, int | None]:
        view = self._get("bufferViews", index)
        data = self.buffer(int(view["buffer"]))
        start, length = int(view.get("byteOffset", 0)), int(view["byteLength"])
        if start + length > len(data):
            raise self.fail(f"bufferViews[{index}] runs past its buffer (truncated file?)")
        return data, start, view.get("byteStride")

    def accessor(self, index: int) -> np.ndarray:
        acc = self._get("accessors", index)
        dtype = np.dtype(COMPONENTS[acc["componentType"]]).newbyteorder("<")
        width, count = WIDTH[acc["type"]], int(acc["count"])
        if "bufferView" in acc:
            out = self._elements(int(acc["bufferView"]), int(acc.get("byteOffset", 0)), dtype, width,
                                 count, f"accessors[{index}]")
        else:  # glTF 2.0, 3.6.2.3: without a bufferView the accessor starts as zeros
            out = np.zeros((count, width), dtype)
        if "sparse" in acc:  # glTF 2.0, 3.6.2.3: listed elements replaced
            out = self._apply_sparse(acc["sparse"], out, dtype, width, f"accessors[{index}]")
        if acc.get("normalized") and dtype.type in NORMALISED:
            return np.maximum(out / NORMALISED[dtype.type], -1.0)
        return out.astype(np.float64) if dtype.kind == "f" else out

    def _elements(self, view: int, offset: int, dtype: np.dtype, width: int, count: int,
                  what: str) -> np.ndarray:
        """[count, width] elements of `dtype` from bufferViews[view] at `offset` (its stride)."""
        data, start, stride = self.view_bytes(view)
        start += offset
        item = dtype.itemsize * width
        stride = int(stride or item)
        end = start + stride * (count - 1) + item
        if end > len(data):
            raise self.fail(f"{what} runs past its buffer (truncated file?)")
        raw = np.frombuffer(data, np.uint8, count=end - start, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, (count, item), (stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def _apply_sparse(self, sparse: dict, out: np.ndarray, dtype: np.dtype, width: int,
                      what: str) -> np.ndarray:
        n, idx, val = int(sparse["count"]), sparse["indices"], sparse["values"]
        index_type = np.dtype(COMPONENTS[idx["componentType"]]).newbyteorder("<")
        rows = self._elements(int(idx["bufferView"]), int(idx.get("byteOffset", 0)), index_type, 1, n,
                              f"{what}.sparse.indices")[:, 0].astype(np.int64)
        if n and (rows.min() < 0 or rows.max() >= len(out)):
            raise self.fail(f"{what}: sparse indices out of range")
        out = out.copy()
        out[rows] = self._elements(int(val["bufferView"]), int(val.get("byteOffset", 0)), dtype, width,
                                   n, f"{what}.sparse.values")
        return out

    def image(self, tex_index: int) -> np.ndarray:
        from PIL import Image

        tex = self._get("textures", tex_index)
        if "source" not in tex:
            raise self.fail(f"textures[{tex_index}] has no source image (extension-only?)")
        img = self._get("images", int(tex["source"]))
        if "bufferView" in img:
            data, start, _ = self.view_bytes(int(img["bufferView"]))
            view = self._get("bufferViews", int(img["bufferView"]))
            blob = data[start:start + int(view["byteLength"])]
        elif img.get("uri", "").startswith("data:"):
            blob = base64.b64decode(img["uri"].split(",", 1)[1])
        else:
            file = self.path.parent / img.get("uri", "")
            if not file.is_file():
                raise self.fail(f"image file {file} not found")
            blob = file.read_bytes()
        try:
            pil = Image.open(io.BytesIO(blob))
            pil.load()
        except Exception as e:  # Pillow raises many types for bad images
            raise self.fail(f"images[{tex['source']}] is not a readable image ({e})") from e
        return image_rgba(pil)


def image_rgba(pil) -> np.ndarray:
    """[H, W, 4] float64 in [0, 1] of a decoded texture (alpha 1 where the image has none).
    16-bit greyscale PNGs (Pillow modes ``I;16*`` / ``I``) are read at full depth:
    ``convert("RGB")`` would clip them to 8 bits."""
    if pil.mode.startswith("I;16") or pil.mode == "I":
        grey = np.clip(np.asarray(pil, dtype=np.float64) / 65535.0, 0.0, 1.0)
        return np.concatenate([np.repeat(grey[..., None], 3, axis=-1), np.ones_like(grey)[..., None]], -1)
    return np.asarray(pil.convert("RGBA"), dtype=np.float64) / 255.0


def is_degenerate(linear: np.ndarray, rtol: float = 1e-9) -> bool:
    """A node's 3x3 world transform flattens space (a scale of 0 on some axis): its smallest
    singular value is 0 relative to its largest. Relative, not an absolute determinant: a product
    model authored in 0.1 mm and scaled by 1e-4 to metres has det 1e-12 and is not degenerate."""
    sv = np.linalg.svd(np.asarray(linear, np.float64), compute_uv=False)
    return not np.isfinite(sv).all() or sv[0] == 0 or sv[-1] <= rtol * sv[0]


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = R * np.asarray(node.get("scale", [1.0, 1.0, 1.0]))[None, :]
    m[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return m


def _texcoord(info: dict) -> int:
    """The UV set a texture info reads (KHR_texture_transform's ``texCoord`` overrides)."""
    ext = info.get("extensions", {}).get(TEXTURE_TRANSFORM, {})
    return int(ext.get("texCoord", info.get("texCoord", 0)))


def _sampling(r: _Reader, info: dict) -> TextureSampling:
    tex = r._get("textures", int(info["index"]))
    sampler = r._get("samplers", int(tex["sampler"])) if "sampler" in tex else {}
    ext = info.get("extensions", {}).get(TEXTURE_TRANSFORM)
    matrix = TextureSampling().matrix if ext is None else texture_transform_matrix(ext)
    return TextureSampling(texcoord=_texcoord(info), matrix=matrix, wrap_s=int(sampler.get("wrapS", REPEAT)),
                           wrap_t=int(sampler.get("wrapT", REPEAT)))


def _material(r: _Reader, index: int | None, uv_sets: frozenset, ignored: list[str]) -> Material:
    if index is None:
        ignored.append("primitive without material: glTF default material")
        return Material()
    mat = r._get("materials", index)
    name = mat.get("name", f"materials[{index}]")
    for key in ("normalTexture", "occlusionTexture", "emissiveTexture"):
        if key in mat:
            ignored.append(f"{name}: {key}")
    alpha_mode = mat.get("alphaMode", "OPAQUE")
    outside = [f"alphaMode {alpha_mode}"] if alpha_mode == "BLEND" else []
    outside += sorted(e for e in mat.get("extensions", {}) if e.startswith("KHR_materials_"))
    for item in outside:  # drawn with the metallic-roughness BRDF; pixels in the scene's mask
        ignored.append(f"{name}: {item} drawn as opaque metallic-roughness (outside_brdf mask)")
    pbr = mat.get("pbrMetallicRoughness")
    coverage = dict(alpha_mode=alpha_mode, alpha_cutoff=float(mat.get("alphaCutoff", 0.5)),
                    double_sided=bool(mat.get("doubleSided", False)), outside_brdf=tuple(outside))
    if pbr is None:
        ignored.append(f"{name}: no pbrMetallicRoughness, glTF defaults")
        return Material(name=name, **coverage)
    factor = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), float)
    out = Material(base_color=factor[:3], roughness=float(pbr.get("roughnessFactor", 1.0)),
                   metallic=float(pbr.get("metallicFactor", 1.0)), name=name,
                   base_alpha=float(factor[3]) if len(factor) > 3 else 1.0, **coverage)
    for key, attr in (("baseColorTexture", "base_color"),
                      ("metallicRoughnessTexture", "metallic_roughness")):
        if key not in pbr:
            continue
        if _texcoord(pbr[key]) not in uv_sets:
            ignored.append(f"{name}: {key} without TEXCOORD_{_texcoord(pbr[key])}, factor only")
            continue
        rgba = r.image(int(pbr[key]["index"]))
        setattr(out, f"{attr}_texture", rgba[..., :3])
        setattr(out, f"{attr}_sampling", _sampling(r, pbr[key]))
        if attr == "base_color" and out.cut_out and (rgba[..., 3] < 1).any():
            out.base_color_alpha_texture = rgba[..., 3]
    return out


def _draco(r: _Reader, ext: dict) -> dict[str, np.ndarray]:
    """Decode a KHR_draco_mesh_compression primitive (DracoPy): attributes + indices."""
    try:
        import DracoPy
    except ImportError as e:
        raise r.fail(f"uses {DRACO}; pip install DracoPy to read it") from e
    data, start, _ = r.view_bytes(int(ext["bufferView"]))
    view = r._get("bufferViews", int(ext["bufferView"]))
    try:
        mesh = DracoPy.decode(data[start:start + int(view["byteLength"])])
    except Exception as e:  # DracoPy raises its own failure types
        raise r.fail(f"Draco data cannot be decoded ({e})") from e
    out = {"indices": np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)}
    for name, uid in ext["attributes"].items():
        attr = mesh.get_attribute_by_unique_id(int(uid))
        if attr is not None and name in ("POSITION", "NORMAL", "TEXCOORD_0"):
            out[name] = np.asarray(attr["data"], dtype=np.float64)
    if "POSITION" not in out:
        raise r.fail("Draco primitive without POSITION")
    return out


def read_gltf(path: str | Path) -> Asset:
    """Read `path` (see module docstring). Raises GLTFError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise GLTFError(f"{path}: file not found")
    r = _Reader(path)
    required = [e for e in r.gltf.get("extensionsRequired", []) if e not in SUPPORTED_EXTENSIONS]
    if required:
        raise r.fail(f"requires glTF extensions {required}, which this reader cannot honour")
    ignored = [f"extension {e}" for e in r.gltf.get("extensionsUsed", []) if e not in SUPPORTED_EXTENSIONS]
    scenes = r.gltf.get("scenes", [])
    roots = (scenes[int(r.gltf.get("scene", 0))]["nodes"] if scenes else
             list(range(len(r.gltf.get("nodes", [])))))
    prims: list[Primitive] = []
    materials: dict = {}
    try:
        stack = [(int(n), np.eye(4)) for n in roots]
        while stack:
            idx, parent = stack.pop()
            node = r._get("nodes", idx)
            world = parent @ _node_matrix(node)
            stack += [(int(c), world) for c in node.get("children", [])]
            if "mesh" not in node:
                continue
            for p in r._get("meshes", int(node["mesh"]))["primitives"]:
                if p.get("mode", 4) != 4:
                    raise r.fail(f"primitive mode {p['mode']} is not triangles")
                attrs = p["attributes"]
                if DRACO in p.get("extensions", {}):
                    data = _draco(r, p["extensions"][DRACO])
                    pos, faces = data["POSITION"], data["indices"]
                else:
                    data = {k: r.accessor(int(v)) for k, v in attrs.items()
                            if k in ("NORMAL", "TEXCOORD_0", "TEXCOORD_1", "COLOR_0")}
                    pos = r.accessor(int(attrs["POSITION"]))
                    faces = (r.accessor(int(p["indices"])).reshape(-1, 3) if "indices" in p
                             else np.arange(len(pos)).reshape(-1, 3))
                if len(faces) == 0 or faces.max() >= len(pos):
                    raise r.fail("primitive indices out of range or empty")
                lin = Y_UP_TO_Z_UP @ world[:3, :3]
                if is_degenerate(lin):  # e.g. a node scaled to 0: no visible surface
                    ignored.append(f"nodes[{idx}]: degenerate transform (scale 0), its mesh is not drawn")
                    continue
                v = pos @ lin.T + Y_UP_TO_Z_UP @ world[:3, 3]
                n = None
                if "NORMAL" in data:
                    n = data["NORMAL"] @ np.linalg.inv(lin)  # rows of (L^-T n)
                    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
                uv, uv1 = data.get("TEXCOORD_0"), data.get("TEXCOORD_1")
                colour = None if data.get("COLOR_0") is None else np.asarray(data["COLOR_0"], np.float64)
                color = None if colour is None else colour[:, :3]
                alpha = colour[:, 3] if colour is not None and colour.shape[1] == 4 else None
                if np.linalg.det(lin) < 0:  # mirrored node: keep counter-clockwise faces
                    faces = faces[:, ::-1]
                uv_sets = frozenset(k for k, a in ((0, uv), (1, uv1)) if a is not None)
                key = (p.get("material"), uv_sets)
                if key not in materials:
                    materials[key] = _material(r, p.get("material"), uv_sets, ignored)
                prims.append(Primitive(v, faces.astype(np.int64), n, uv, materials[key], uv1=uv1, color=color,
                                       alpha=alpha))
    except (KeyError, IndexError, TypeError) as e:
        raise r.fail(f"malformed glTF ({type(e).__name__}: {e})") from e
    if not prims:
        raise r.fail("no triangle primitives in the default scene")
    ignored = sorted(set(ignored))
    for item in ignored:
        log.warning("%s: ignored %s", path, item)
    return Asset(path, prims, ignored)
