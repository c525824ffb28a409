"""Objects of several parts, each with its own material (the training pool's `data.parts`, issue 42).

Real assets are several parts with their own materials: a metal bottle with a painted label and
a plastic cap, a lamp with a brass stem and a fabric shade. A pool scene drawn to be multi-part
(`data.parts.share`) is split into 2-4 parts (`data.parts.count`), each a full recipe of its own
class (`gspi.data.procedural.materials.sample_material`), by one of two layouts:

- ``bands``: cuts across a random axis (cap / label / body), each cut warped by value noise;
- ``cells``: the nearest of k random centres (a handle, a lid), the distance warped by noise.

Whatever the layout, a multi-part object holds a metal part beside a dielectric one half of
the time (real objects are mostly mixed), and never only metal.

Per part (and, when set, for the single-class scenes too), three variations widen what the pool
holds beyond the benchmark's classes:

- ``metal_f0: wide``: a metal part's base colour is drawn anywhere an artist may put it (linear
  value in [0.03, 1], any hue at low saturation; Suzanne's is 0.10), instead of the table of
  physical F0 (titanium's 0.45 is the darkest there);
- ``roughness_spread: s``: the part's roughness shifted by U(-s, s) (clamped as every roughness);
- ``texture: a``: a fBm texture of amplitude a over the part's albedo and roughness (print,
  grime, wear), at a drawn frequency;
- ``look_swap: p``: with probability p a dielectric part wears the albedo pattern of another
  dielectric class (its ``look``: a checker on a matte fabric finish, a tartan on glossy plastic)
  while its roughness and metallic stay its own class's. In the benchmark's classes a pattern
  names its finish (checker and stripes are glossy plastic, tiles are glazed); real prints are on
  any finish, and a prior that learned the pattern instead of the shading guesses a finish from a
  print (the feature-test assets: flat prints with glTF's default roughness 1.0);
- ``matte_finish: p``: with probability p a dielectric part keeps its class's look but takes a
  matte finish, a roughness drawn in ``MATTE_ROUGHNESS`` (paper, card, unglazed clay, matte paint).
  The benchmark's classes put half their dielectric finishes below 0.25 (glossy plastic, glazed
  ceramic); the objects users bring are mostly matte (glTF's default roughness is 1.0), and a
  prior calibrated on the classes guesses glossy where the shading cannot tell (issue 42,
  docs/log/diary.md "Session 16").

The recipes stay JSON (`scene.json`'s `generator.material`); `evaluate_material` reads the
``parts`` entry and the per-part keys ``f0``, ``roughness_shift``, ``texture``, ``look`` and ``finish_roughness``. With
the defaults (share 0, physical F0, no spread, no texture, no look swap, no matte finish) nothing
is drawn and no key is added, so a pool made without `data.parts` keeps every byte, and
``look_swap: 0`` and ``matte_finish: 0`` keep every byte of a pool made with the other keys (tested).
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from gspi.data.procedural import patterns
from gspi.data.procedural.materials import MATERIAL_CLASSES, METAL_CLASSES, sample_material
from gspi.strict_config import dataclass_from_dict

LAYOUTS = ("bands", "cells")
METAL_F0_MODES = ("physical", "wide")
MATTE_ROUGHNESS = (0.7, 1.0)  # data.parts.matte_finish: the roughness range of a matte finish


@dataclass(frozen=True)
class PartsConfig:
    """``data.parts`` (conf/data/stage2_pool.yaml); the defaults draw nothing. Built and checked
    by :meth:`from_mapping` (``gspi.strict_config``: unknown keys, types, ``RANGES``, ``CHOICES``)."""

    share: float = 0.0                      # share of pool scenes made of several parts
    count: tuple = (2, 4)                   # [min, max] parts of such a scene
    layouts: tuple = LAYOUTS                # drawn uniformly per multi-part scene
    metal_f0: str = "physical"              # physical | wide (see module docstring)
    roughness_spread: float = 0.0           # per-part roughness shift U(-s, s)
    texture: float = 0.0                    # per-part fBm amplitude over albedo and roughness
    look_swap: float = 0.0                  # share of dielectric parts wearing another class's pattern
    matte_finish: float = 0.0               # share of dielectric parts given a matte finish (MATTE_ROUGHNESS)

    RANGES: ClassVar[dict] = {"share": (0.0, 1.0), "roughness_spread": (0.0, 0.5), "texture": (0.0, 1.0),
                              "look_swap": (0.0, 1.0), "matte_finish": (0.0, 1.0)}
    CHOICES: ClassVar[dict] = {"metal_f0": METAL_F0_MODES}

    def __post_init__(self):  # the two list-valued keys, which the strict layer does not look inside
        count = tuple(int(c) for c in self.count)
        if len(count) != 2 or not 2 <= count[0] <= count[1] <= 8:
            raise ValueError(f"data.parts.count must be [min, max] with 2 <= min <= max <= 8, got {list(self.count)}")
        object.__setattr__(self, "count", count)
        bad = [x for x in self.layouts if x not in LAYOUTS]
        if bad or not self.layouts:
            raise ValueError(f"data.parts.layouts: {list(self.layouts)}; allowed: {', '.join(LAYOUTS)}")
        object.__setattr__(self, "layouts", tuple(self.layouts))

    @classmethod
    def from_mapping(cls, node) -> "PartsConfig":
        return dataclass_from_dict(cls, dict(node or {}), "data.parts")

    @property
    def varies_parts(self) -> bool:
        """True when a part's recipe gets variations (wide F0, roughness spread, texture, look, finish)."""
        return (self.metal_f0 != "physical" or self.roughness_spread > 0 or self.texture > 0
                or self.look_swap > 0 or self.matte_finish > 0)

    @property
    def is_default(self) -> bool:
        return self.share == 0 and not self.varies_parts


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def part_classes(primary_class: str, n: int, rng: np.random.Generator) -> list[str]:
    """The classes of an n-part object whose first part is `primary_class`: the others drawn
    from the other classes; then, half of the time, one metal part beside dielectric ones, and
    never all metal."""
    others = [c for c in MATERIAL_CLASSES if c != primary_class]
    classes = [primary_class] + [others[int(rng.integers(0, len(others)))] for _ in range(n - 1)]
    wants_metal = rng.uniform() < 0.5
    dielectrics = [c for c in MATERIAL_CLASSES if c not in METAL_CLASSES]
    if wants_metal and not any(c == "metal" for c in classes):
        classes[1 + int(rng.integers(0, n - 1))] = "metal"
    if all(c in METAL_CLASSES for c in classes):
        classes[1 + int(rng.integers(0, n - 1))] = dielectrics[int(rng.integers(0, len(dielectrics)))]
    return classes


def vary_part(recipe: dict, cfg: PartsConfig, rng: np.random.Generator) -> dict:
    """`recipe` with the configured variations (a new dict; the class's own keys untouched)."""
    out = dict(recipe)
    if cfg.metal_f0 == "wide" and recipe["class"] == "metal":
        rgb = colorsys.hsv_to_rgb(rng.uniform(), _u(rng, 0.0, 0.5), _u(rng, 0.03, 1.0))
        out["f0"] = [float(c) for c in rgb]  # linear
    if cfg.roughness_spread > 0:
        out["roughness_shift"] = _u(rng, -cfg.roughness_spread, cfg.roughness_spread)
    if cfg.texture > 0:
        out["texture"] = {"amplitude": _u(rng, 0.3, 1.0) * cfg.texture,
                          "frequency": _u(rng, 2.0, 10.0), "seed": int(rng.integers(0, 2**20))}
    dielectric = recipe["class"] not in METAL_CLASSES
    if cfg.look_swap > 0 and dielectric and rng.uniform() < cfg.look_swap:
        others = [c for c in MATERIAL_CLASSES if c not in METAL_CLASSES and c != recipe["class"]]
        out["look"] = sample_material(others[int(rng.integers(0, len(others)))], rng)
    if cfg.matte_finish > 0 and dielectric and rng.uniform() < cfg.matte_finish:
        out["finish_roughness"] = _u(rng, *MATTE_ROUGHNESS)
    return out


def sample_parts(primary: dict, cfg: PartsConfig, rng: np.random.Generator) -> dict:
    """A multi-part recipe whose first part is `primary` (see module docstring)."""
    n = int(rng.integers(cfg.count[0], cfg.count[1] + 1))
    classes = part_classes(primary["class"], n, rng)
    recipes = [primary] + [sample_material(c, rng) for c in classes[1:]]
    recipes = [vary_part(r, cfg, rng) for r in recipes]
    layout = cfg.layouts[int(rng.integers(0, len(cfg.layouts)))]
    if layout == "bands":
        axis = rng.normal(size=3)
        geometry = {"axis": (axis / np.linalg.norm(axis)).tolist(),
                    "cuts": sorted(_u(rng, -0.6, 0.6) for _ in range(n - 1))}
    else:
        centres = rng.normal(size=(n, 3))
        centres = 0.6 * centres / np.linalg.norm(centres, axis=1, keepdims=True)
        geometry = {"centres": centres.tolist()}
    return {"class": primary["class"], "seed": primary["seed"],
            "parts": {"layout": layout, **geometry, "warp": _u(rng, 0.05, 0.3),
                      "noise_seed": int(rng.integers(0, 2**20)), "materials": recipes}}


__all__ = ["LAYOUTS", "MATTE_ROUGHNESS", "PartsConfig", "part_classes", "sample_parts", "vary_part"]
