"""Options of the glTF export of a PBR-GS asset (conf/gspi_export_asset.yaml), checked at the door.

``ExportConfig.from_dict`` builds it from the resolved Hydra node and refuses unknown keys and
values of the wrong type or range (``gspi.strict_config``), naming the dotted key.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar

from gspi.strict_config import dataclass_from_dict


@dataclass
class MeshConfig:
    image_size: int = 256          # lattice depth renders (px); 2x the demo's 128 px images
    alpha_threshold: float = 0.5   # a pixel's median depth is the surface's where alpha exceeds this
    resolution: int = 64           # voxels along the largest side of the surfels' bounding box
    margin: float = 0.05           # grid padding, fraction of that side
    truncation_voxels: float = 4.0  # TSDF truncation in voxels
    min_fragment: float = 0.01     # components with fewer faces than this fraction are dropped
    # TSDF levels tried (truncation units, 0 = the median-depth surface); the one whose mesh
    # silhouette best matches the asset's alpha at the lattice views is kept (docs/EXPORT.md)
    levels: list = field(default_factory=lambda: [0.0, 0.125, 0.25, 0.375, 0.5])

    RANGES: ClassVar[dict] = {"image_size": (16, 4096), "alpha_threshold": (0.0, 1.0), "resolution": (8, 512),
                              "margin": (0.0, 1.0), "truncation_voxels": (0.5, 64.0), "min_fragment": (0.0, 1.0)}

    def __post_init__(self) -> None:
        if not self.levels or not all(isinstance(v, (int, float)) and 0.0 <= v < 1.0 for v in self.levels):
            raise ValueError(f"export.mesh.levels={self.levels!r}: must be a non-empty list of numbers in [0, 1)")


@dataclass
class TextureConfig:
    size: int = 512                # texture side (px); both textures are size x size
    padding: int = 4               # atlas padding between charts (texels of the atlas xatlas packs)
    source: str = "views"          # views: the lattice renders where a view sees the texel | surfels: k nearest
    neighbours: int = 16           # surfels weighed per texel (k nearest centres; texels no view sees)
    depth_tolerance_voxels: float = 1.5  # a view sees a texel when |z - rendered depth| < this many voxels

    RANGES: ClassVar[dict] = {"size": (16, 8192), "padding": (0, 64), "neighbours": (1, 256),
                              "depth_tolerance_voxels": (0.0, 64.0)}
    CHOICES: ClassVar[dict] = {"source": ("views", "surfels")}


@dataclass
class ExportConfig:
    mesh: MeshConfig = field(default_factory=MeshConfig)
    texture: TextureConfig = field(default_factory=TextureConfig)
    preview: bool = True           # also write <out stem>_preview.png (gspi.export.preview)
    backend: str = "auto"          # rasterizer backend for the lattice renders

    CHOICES: ClassVar[dict] = {"backend": ("auto", "torch", "numba", "gsplat")}

    @classmethod
    def from_dict(cls, data: dict, where: str = "export") -> "ExportConfig":
        return dataclass_from_dict(cls, dict(data), where)

    def to_dict(self) -> dict:
        return asdict(self)
