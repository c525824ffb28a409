"""Stage I hyperparameters (`conf/stage1/*.yaml`), built strictly from plain dicts.

    cfg = Stage1Config.from_dict({"image_size": 128, "outliers": {"std_ratio": 2.0}})

Every key is checked: an unknown key raises ``ValueError`` naming it (a typo in an override must
not silently run the default). Filter details: ``gspi.stage1.filters``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar, Mapping, Optional

from gspi.data.lattice import CANONICAL_LATTICE
from gspi.strict_config import dataclass_from_dict


@dataclass
class OutlierConfig:
    """Filter (i), global statistical outlier removal (Open3D's definition)."""

    enabled: bool = True
    k: int = 16               # neighbours for the mean distance
    std_ratio: float = 2.0    # keep mean_dist <= mean + std_ratio * std

    RANGES: ClassVar[dict] = {"k": (1, None), "std_ratio": (0.0, None)}


@dataclass
class MaskConsistencyConfig:
    """Filter (ii), cross-view foreground-mask consistency."""

    enabled: bool = True
    max_violations: int = 1   # views in which the point may land on background
    dilate_px: int = 1        # silhouette tolerance


@dataclass
class DepthConsensusConfig:
    """Filter (iii), depth consensus across neighbouring lattice views."""

    enabled: bool = True
    num_neighbours: int = 6   # closest lattice views to the source view
    tolerance_px: float = 3.0  # in pixel footprints at the point's depth
    max_violations: int = 0   # neighbour views that may see empty space where the point is
    window_px: int = 1        # compare with the nearest surface within this many px (edges)


@dataclass
class Stage1Config:
    """Stage I (paper, "Point Cloud Extraction"): lattice render, unprojection, 3 filters."""

    name: str = "default"          # the conf/stage1 option it came from (recorded in stage1.json)
    image_size: int = 128          # lattice render size in px, square (paper: 512)
    # the lattice (defaults: gspi.data.lattice.CANONICAL_LATTICE); its renders carry these cameras
    # on to Stages II and III, so a non-canonical lattice stays consistent end to end
    num_views: int = CANONICAL_LATTICE["num_views"]
    radius: float = CANONICAL_LATTICE["radius"]
    fov_deg: float = CANONICAL_LATTICE["fov_deg"]
    min_elevation_deg: float = CANONICAL_LATTICE["min_elevation_deg"]
    alpha_threshold: float = 0.5   # foreground = rendered opacity >= this
    outliers: OutlierConfig = field(default_factory=OutlierConfig)
    mask_consistency: MaskConsistencyConfig = field(default_factory=MaskConsistencyConfig)
    depth_consensus: DepthConsensusConfig = field(default_factory=DepthConsensusConfig)
    max_points: Optional[int] = None  # seeded uniform subsample after filtering (None: all, paper)
    seed: int = 0                  # of that subsample

    # Allowed values, checked by gspi.strict_config at start-up (inclusive; None = open).
    RANGES: ClassVar[dict] = {"image_size": (8, 8192), "num_views": (1, None), "radius": (1e-6, None),
                              "fov_deg": (1.0, 179.0), "min_elevation_deg": (-90.0, 90.0),
                              "alpha_threshold": (0.0, 1.0), "max_points": (1, None), "seed": (0, None)}

    @property
    def lattice(self) -> dict:
        """Keyword arguments of ``gspi.data.lattice.lattice_cameras`` (less the image size)."""
        return {"num_views": self.num_views, "radius": self.radius, "fov_deg": self.fov_deg,
                "min_elevation_deg": self.min_elevation_deg}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Stage1Config":
        """Builds the config from plain nested dicts; unknown keys raise ``ValueError``."""
        return dataclass_from_dict(cls, data, "stage1")

    def to_dict(self) -> dict:
        return asdict(self)


