"""Controlled pairs: test scenes that differ in exactly one material property (issue 52, item 4).

A pair is two scenes with the same shape, base colour, capture and relight environments,
cameras and sub-pixel jitter, whose uniform material (`plain_material`) differs only in

- ``roughness``: a glossy and a matte dielectric (members ``glossy`` / ``matte``, roughness
  ``glossy_roughness`` / ``matte_roughness``), base colour a random sRGB hue;
- ``metal``: a dielectric and a metal (members ``dielectric`` / ``metal``, metallic 0 / 1, both at
  ``metal_roughness``), base colour a physical metal's F0 (`METAL_F0`: a gold-like dielectric
  beside gold).

So a method that reads the material from the photos orders each pair; one that guesses from the
colour or the shape cannot (both members look alike to it). Every (kind, shape family, colour
index) is one pair, drawing from ``SeedSequence([seed, PAIRS_NAMESPACE, kind, family, colour])``:
no benchmark (namespace 0) or pool (2) scene shares a draw, and a pair does not depend on which
others are made. ``gspi-data preset=controlled_pairs out=DIR`` writes the scenes as the ``test``
split of a canonical dataset and the manifest

    <out>/pairs.json   {"format": "gspi-controlled-pairs", "version": 1, "seed": int,
                        "pairs": [{"id", "kind", "family", "albedo_linear": [3],
                                   "scenes": {member: scene name}, "values": {member: value}}]}

whose members are listed low value first (`KIND_MEMBERS`): glossy before matte, dielectric before
metal. `benchmarks/bench_controlled_pairs.py` scores a gspi-run folder against it.
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch

from eval.common.atomic import write_json_atomic
from eval.common.colorspace import srgb_to_linear
from eval.common.layout import read_json_object
from gspi.data.environments import env_names
from gspi.data.procedural.materials import METAL_F0, plain_material
from gspi.data.procedural.scene_recipe import held_out_view_directions
from gspi.data.procedural.sdf_shapes import FAMILIES, sample_shape
from gspi.strict_config import dataclass_from_dict

PAIRS_NAMESPACE = 3    # benchmark scenes: 0, dataset-level draws: 1, the training pool: 2
KIND_MEMBERS = {"roughness": ("glossy", "matte"), "metal": ("dielectric", "metal")}
MANIFEST = "pairs.json"
MANIFEST_FORMAT, MANIFEST_VERSION = "gspi-controlled-pairs", 1


@dataclass(frozen=True)
class ControlledPairsConfig:
    """``data.controlled_pairs`` (conf/data/controlled_pairs.yaml); built by :meth:`from_mapping`."""

    kinds: tuple = tuple(KIND_MEMBERS)            # roughness | metal
    families: tuple = ("sphere", "torus", "rounded_box")  # shape families (sdf_shapes.FAMILIES)
    colours: int = 3                              # pairs per (kind, family), one base colour each
    glossy_roughness: float = 0.1
    matte_roughness: float = 0.8
    metal_roughness: float = 0.2                  # both members of a metal pair

    RANGES: ClassVar[dict] = {"colours": (1, len(METAL_F0)), "glossy_roughness": (0.02, 1.0),
                              "matte_roughness": (0.02, 1.0), "metal_roughness": (0.02, 1.0)}

    def __post_init__(self):  # the list-valued keys, which the strict layer does not look inside
        for key, allowed in (("kinds", tuple(KIND_MEMBERS)), ("families", FAMILIES)):
            values = tuple(getattr(self, key))
            bad = [v for v in values if v not in allowed]
            if bad or not values or len(set(values)) != len(values):
                raise ValueError(f"data.controlled_pairs.{key}: {list(values)}; distinct values "
                                 f"of {', '.join(allowed)}")
            object.__setattr__(self, key, values)
        if not self.glossy_roughness < self.matte_roughness:
            raise ValueError("data.controlled_pairs: glossy_roughness must be below matte_roughness, got "
                             f"{self.glossy_roughness} and {self.matte_roughness}")

    @classmethod
    def from_mapping(cls, node) -> "ControlledPairsConfig":
        return dataclass_from_dict(cls, dict(node or {}), "data.controlled_pairs")


def pair_rng(seed: int, *key: int) -> np.random.Generator:
    """Generator of (kind, family[, colour]) indices of dataset `seed` (module docstring)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), PAIRS_NAMESPACE, *map(int, key)]))


def pair_colour(seed: int, kind: str, family: str, colour: int, rng: np.random.Generator) -> list[float]:
    """Linear base colour [3] of a pair: a random sRGB hue (roughness) or a metal's F0 (metal,
    the family's own seeded order of `METAL_F0`, so its pairs show different metals)."""
    if kind == "metal":
        names = sorted(METAL_F0)
        order = pair_rng(seed, list(KIND_MEMBERS).index(kind), FAMILIES.index(family)).permutation(len(names))
        return list(METAL_F0[names[int(order[colour])]])
    srgb = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(0.3, 0.9), rng.uniform(0.4, 0.9))
    return [float(c) for c in srgb_to_linear(torch.tensor(srgb, dtype=torch.float64))]


def member_values(kind: str, cfg: ControlledPairsConfig) -> dict[str, tuple[float, float]]:
    """member -> (roughness, metallic) of a pair of `kind`."""
    if kind == "roughness":
        return {"glossy": (cfg.glossy_roughness, 0.0), "matte": (cfg.matte_roughness, 0.0)}
    return {"dielectric": (cfg.metal_roughness, 0.0), "metal": (cfg.metal_roughness, 1.0)}


def pair_recipes(seed: int, kind: str, family: str, colour: int, index: int, cfg: ControlledPairsConfig, *,
                 num_test_views: int, num_val_views: int, num_relight_envs: int,
                 lattice: dict) -> tuple[dict, list[dict]]:
    """(manifest entry, the two scene recipes, low value first) of pair `index` (id c<index>)."""
    pair_id = f"c{index:02d}"
    key = (list(KIND_MEMBERS).index(kind), FAMILIES.index(family), colour)
    rng = pair_rng(seed, *key)
    shape = sample_shape(family, rng)
    albedo = pair_colour(seed, kind, family, colour, rng)
    capture, heldout = env_names("capture"), env_names("heldout")
    if not 0 <= num_relight_envs <= len(heldout):
        raise ValueError(f"num_relight_envs must be in [0, {len(heldout)}], got {num_relight_envs}")
    relight = sorted(rng.choice(len(heldout), size=num_relight_envs, replace=False).tolist())
    test_dirs, val_dirs = held_out_view_directions(
        pair_rng(seed, *key, 1), pair_rng(seed, *key, 2), num_test_views=num_test_views,
        num_val_views=num_val_views, num_lattice_views=lattice["num_views"],
        min_elevation_deg=lattice.get("min_elevation_deg", 0.0))
    shared = {"index": int(index), "family": family, "shape": shape,
              "capture_env": capture[int(rng.integers(0, len(capture)))],
              "relight_envs": [heldout[i] for i in relight],
              "test_directions": test_dirs.tolist(), "val_directions": val_dirs.tolist(),
              "view_seed": int(rng.integers(0, 2**31 - 1)), "pairs_namespace": PAIRS_NAMESPACE}
    recipes, scenes, values = [], {}, {}
    for member, (rough, metal) in member_values(kind, cfg).items():
        name = f"{pair_id}_{family}_{member}"
        recipes.append({**shared, "name": name, "material": plain_material(albedo, rough, metal),
                        "pair": {"id": pair_id, "kind": kind, "member": member}})
        scenes[member] = name
        values[member] = rough if kind == "roughness" else metal
    entry = {"id": pair_id, "kind": kind, "family": family, "albedo_linear": albedo,
             "scenes": scenes, "values": values}
    return entry, recipes


def controlled_pairs(seed: int, cfg: ControlledPairsConfig, **views) -> tuple[list[dict], list[dict]]:
    """(manifest entries, scene recipes) of every pair: kinds, then families, then colours.

    Args:
        views: `pair_recipes`' num_test_views, num_val_views, num_relight_envs, lattice.
    """
    entries, recipes = [], []
    for kind in cfg.kinds:
        for family in cfg.families:
            for colour in range(cfg.colours):
                entry, pair = pair_recipes(seed, kind, family, colour, len(entries), cfg, **views)
                entries.append(entry)
                recipes += pair
    return entries, recipes


def write_manifest(out_dir: Path, seed: int, entries: list[dict]) -> Path:
    path = Path(out_dir) / MANIFEST
    write_json_atomic(path, {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "seed": int(seed),
                             "pairs": entries})
    return path


def read_manifest(path: str | Path) -> list[dict]:
    """The pairs of a manifest (a dataset folder or its pairs.json); raises ValueError naming the file."""
    path = Path(path)
    path = path / MANIFEST if path.is_dir() else path
    data = read_json_object(path, error=ValueError, what="controlled-pairs manifest")
    if data.get("format") != MANIFEST_FORMAT or data.get("version") != MANIFEST_VERSION:
        raise ValueError(f"{path}: not a {MANIFEST_FORMAT} v{MANIFEST_VERSION} manifest")
    for p in data["pairs"]:
        if p.get("kind") not in KIND_MEMBERS or list(p.get("scenes", {})) != list(KIND_MEMBERS[p["kind"]]):
            raise ValueError(f"{path}: pair {p.get('id')!r} has kind {p.get('kind')!r} and members "
                             f"{list(p.get('scenes', {}))}; expected {KIND_MEMBERS}")
    return data["pairs"]
