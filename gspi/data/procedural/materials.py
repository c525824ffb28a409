"""Spatially varying PBR material classes of the procedural benchmark.

A material is a JSON-serialisable *recipe* (stored in `scene.json`, key `generator.material`)
evaluated at object-space surface points by `evaluate_material`; patterns come from
`gspi.data.procedural.patterns` (regions, stripes, checker, cellular/Voronoi, text-like glyph stripes,
fBm wear), so maps have sharp material boundaries and high-frequency detail.

Classes (6): rough_plastic, glossy_plastic, metal (polished or brushed, coloured F0),
painted_metal (paint with worn patches of bare metal), fabric, ceramic (glazed tiles with
grout, cobalt glyph decoration and a gold rim band).

Colour spaces: recipe colours are sRGB-encoded in [0, 1] except metal F0 colours, which are
linear reflectances; `evaluate_material` returns LINEAR albedo (the split-sum base colour).
Metallic is binary per region (0 or 1); supersampling makes it fractional only across region
boundaries.

Two-class materials (`mix_materials`, the training pool's `data.material_mix` only): a recipe
with a `mix` entry is split by a noise-warped plane into its own class and a second class
(metal beside a dielectric whenever either is metal), as real assets are (a metal bottle with a
painted label, issue 24). Benchmark scenes never carry one. Objects of 2-4 parts with per-part
variations (the pool's `data.parts`, issue 42): `gspi.data.procedural.material_parts`.

One more class stands outside the six, for controlled scenes only (`gspi.data.controlled_pairs`):
``plain``, one linear base colour, one roughness and one metallic over the whole object
(`plain_material`), so two scenes can differ in exactly one property.
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from eval.common.colorspace import srgb_to_linear
from gspi.data.procedural import patterns

MATERIAL_CLASSES = ("rough_plastic", "glossy_plastic", "metal", "painted_metal", "fabric",
                    "ceramic")
# Linear F0 of common metals (approximate, Naty Hoffman's "Physics and Math of Shading").
METAL_F0 = {"gold": (1.0, 0.78, 0.34), "copper": (0.95, 0.64, 0.54), "silver": (0.97, 0.96, 0.91),
            "aluminium": (0.91, 0.92, 0.92), "brass": (0.91, 0.78, 0.42),
            "iron": (0.56, 0.57, 0.58), "titanium": (0.54, 0.50, 0.45)}


@dataclass
class MaterialSample:
    """Per-point material: albedo_linear [N, 3], roughness [N], metallic [N], all in [0, 1]."""

    albedo_linear: Tensor
    roughness: Tensor
    metallic: Tensor


def _colour(rng: np.random.Generator, *, sat: tuple[float, float] = (0.3, 0.9),
            val: tuple[float, float] = (0.25, 0.9)) -> list[float]:
    """A random sRGB colour (HSV sampling)."""
    rgb = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(*sat), rng.uniform(*val))
    return [float(c) for c in rgb]


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _seed(rng: np.random.Generator) -> int:
    return int(rng.integers(0, 2**20))


def sample_material(material_class: str, rng: np.random.Generator) -> dict:
    """A random recipe of `material_class` (see module docstring)."""
    r: dict = {"class": material_class, "seed": _seed(rng)}
    if material_class == "rough_plastic":
        r.update(colours=[_colour(rng) for _ in range(3)], roughness=_u(rng, 0.55, 0.85),
                 frequency=_u(rng, 1.5, 3.5))
    elif material_class == "glossy_plastic":
        axis = rng.normal(size=3)
        r.update(colours=[_colour(rng), _colour(rng)], roughness=_u(rng, 0.08, 0.25),
                 pattern=["stripes", "checker"][int(rng.integers(0, 2))],
                 axis=(axis / np.linalg.norm(axis)).tolist(), frequency=_u(rng, 2.0, 5.0))
    elif material_class == "metal":
        names = sorted(METAL_F0)
        r.update(metal=names[int(rng.integers(0, len(names)))], finish=["polished", "brushed"][
            int(rng.integers(0, 2))], roughness=_u(rng, 0.05, 0.2),
            brushed_roughness=_u(rng, 0.25, 0.45), enamel=_colour(rng, val=(0.05, 0.3)),
            lines=_u(rng, 3.0, 6.0))
    elif material_class == "painted_metal":
        r.update(paint=_colour(rng), paint_roughness=_u(rng, 0.35, 0.6),
                 bare_f0=[_u(rng, 0.55, 0.75)] * 3, bare_roughness=_u(rng, 0.25, 0.4),
                 wear=_u(rng, 0.55, 0.65), wear_frequency=_u(rng, 2.0, 4.0),
                 text=_colour(rng, sat=(0.0, 0.1), val=(0.85, 0.95)), lines=_u(rng, 3.0, 5.0))
    elif material_class == "fabric":
        r.update(colours=[_colour(rng, val=(0.2, 0.8)) for _ in range(2)],
                 roughness=_u(rng, 0.85, 1.0), weave=_u(rng, 18.0, 36.0),
                 pattern=["tartan", "weave"][int(rng.integers(0, 2))], tartan=_u(rng, 2.0, 4.0))
    elif material_class == "ceramic":
        r.update(glaze=_colour(rng, sat=(0.0, 0.5), val=(0.7, 0.95)), roughness=_u(rng, 0.03, 0.15),
                 grout=_colour(rng, sat=(0.0, 0.1), val=(0.3, 0.5)), tiles=_u(rng, 2.0, 4.0),
                 decoration=_colour(rng, sat=(0.7, 0.9), val=(0.3, 0.6)), rim=_u(rng, 0.55, 0.75),
                 lines=_u(rng, 3.0, 5.0))
    else:
        raise ValueError(f"unknown material class {material_class!r}; "
                         f"allowed: {', '.join(MATERIAL_CLASSES)}")
    return r


METAL_CLASSES = ("metal", "painted_metal")
PLAIN_CLASS = "plain"  # controlled scenes only (module docstring); never drawn by sample_material


def plain_material(albedo_linear: list[float], roughness: float, metallic: float) -> dict:
    """The recipe of a uniform material: linear base colour [3], roughness and metallic in [0, 1]."""
    return {"class": PLAIN_CLASS, "seed": 0, "albedo_linear": [float(c) for c in albedo_linear],
            "roughness": float(roughness), "metallic": float(metallic)}


def mix_materials(primary: dict, rng: np.random.Generator) -> dict:
    """`primary` with a second class over part of the object (see module docstring).

    The second class is a dielectric when `primary` is metallic, else metal half of the
    time and another dielectric class otherwise; the split is the plane ``q . axis = offset``
    (offset uniform in [-0.35, 0.35] of the unit-sphere frame) warped by value noise.
    """
    dielectrics = [c for c in MATERIAL_CLASSES if c not in METAL_CLASSES]
    if primary["class"] in METAL_CLASSES:
        second = dielectrics[int(rng.integers(0, len(dielectrics)))]
    elif rng.uniform() < 0.5:
        second = "metal"
    else:
        others = [c for c in dielectrics if c != primary["class"]]
        second = others[int(rng.integers(0, len(others)))]
    axis = rng.normal(size=3)
    return {**primary, "mix": {"second": sample_material(second, rng),
                               "axis": (axis / np.linalg.norm(axis)).tolist(),
                               "offset": _u(rng, -0.35, 0.35), "warp": _u(rng, 0.1, 0.4),
                               "seed": _seed(rng)}}


def _second_region(mix: dict, q: Tensor) -> Tensor:
    """[N] bool: the points of `q` that carry the second class of a two-class recipe."""
    axis = torch.tensor(mix["axis"], dtype=q.dtype, device=q.device)
    warp = mix["warp"] * (patterns.value_noise(q * 2.5, int(mix["seed"])) - 0.5)
    return q @ axis + warp > mix["offset"]


def _lin(colour_srgb, device: torch.device) -> Tensor:
    return srgb_to_linear(torch.tensor(colour_srgb, dtype=torch.float32, device=device))


def _pick(mask: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Per point: b where mask else a (a, b broadcast to [N] or [N, 3])."""
    m = mask if a.ndim <= 1 and b.ndim <= 1 else mask[:, None]
    return torch.where(m, b, a)


def evaluate_material(recipe: dict, q: Tensor) -> MaterialSample:
    """Evaluate a material recipe at object-space points.

    Args:
        recipe: from `sample_material`.
        q: [N, 3] object-space surface points (unit-sphere frame), float32.
    Returns:
        MaterialSample with linear albedo, on the device of `q`.
    """
    if "parts" in recipe:  # gspi.data.procedural.material_parts
        index = patterns.part_regions(q, recipe["parts"])
        samples = [evaluate_material(r, q) for r in recipe["parts"]["materials"]]
        pick = index[:, None, None].expand(-1, 1, 3)
        albedo = torch.stack([s.albedo_linear for s in samples], 1).gather(1, pick)[:, 0]
        rough = torch.stack([s.roughness for s in samples], 1).gather(1, index[:, None])[:, 0]
        metal = torch.stack([s.metallic for s in samples], 1).gather(1, index[:, None])[:, 0]
        return MaterialSample(albedo, rough, metal)
    if "mix" in recipe:
        own = evaluate_material({k: v for k, v in recipe.items() if k != "mix"}, q)
        second = evaluate_material(recipe["mix"]["second"], q)
        region = _second_region(recipe["mix"], q)
        return MaterialSample(_pick(region, own.albedo_linear, second.albedo_linear),
                              _pick(region, own.roughness, second.roughness),
                              _pick(region, own.metallic, second.metallic))
    n, seed, cls = q.shape[0], int(recipe["seed"]), recipe["class"]
    dev = dict(device=q.device)
    ones, zeros = torch.ones(n, **dev), torch.zeros(n, **dev)

    def lin(colour_srgb) -> Tensor:
        return _lin(colour_srgb, q.device)

    def vec(values) -> Tensor:
        return torch.tensor(values, **dev)

    def full(value: float) -> Tensor:
        return torch.full((n,), value, **dev)
    if cls == "rough_plastic":
        _, _, ident = patterns.voronoi(q * recipe["frequency"], seed)
        k = torch.clamp((ident * 3).long(), 0, 2)
        albedo = torch.stack([lin(c) for c in recipe["colours"]])[k]
        rough = recipe["roughness"] + 0.2 * (patterns.fbm(q * 4.0, seed + 1) - 0.5)
        metal = zeros
    elif cls == "glossy_plastic":
        if recipe["pattern"] == "stripes":
            sel = patterns.stripes(q, vec(recipe["axis"]), recipe["frequency"])
        else:
            sel = patterns.checker(q, recipe["frequency"])
        c0, c1 = (lin(c) for c in recipe["colours"])
        albedo = _pick(sel, c0.expand(n, 3), c1.expand(n, 3))
        rough = recipe["roughness"] + 0.05 * (patterns.value_noise(q * 8.0, seed) - 0.5)
        metal = zeros
    elif cls == "metal":
        f0 = vec(recipe["f0"] if "f0" in recipe else METAL_F0[recipe["metal"]]).expand(n, 3)
        if recipe["finish"] == "brushed":
            streak = patterns.brushed(q, seed)
            rough = recipe["brushed_roughness"] + 0.15 * (streak - 0.5)
            f0 = f0 * (0.9 + 0.1 * streak)[:, None]
        else:
            rough = recipe["roughness"] + 0.04 * (patterns.value_noise(q * 6.0, seed) - 0.5)
        ink = patterns.glyph_stripes(q, seed, lines=recipe["lines"], band=(-0.3, 0.3))
        albedo = _pick(ink, f0, lin(recipe["enamel"]).expand(n, 3))
        rough = _pick(ink, rough, full(0.3))
        metal = _pick(ink, ones, zeros)
    elif cls == "painted_metal":
        worn = patterns.fbm(q * recipe["wear_frequency"], seed, octaves=5) > recipe["wear"]
        ink = patterns.glyph_stripes(q, seed + 5, lines=recipe["lines"], band=(-0.2, 0.4)) & ~worn
        paint = _pick(ink, lin(recipe["paint"]).expand(n, 3), lin(recipe["text"]).expand(n, 3))
        albedo = _pick(worn, paint, vec(recipe["bare_f0"]).expand(n, 3))
        rough = _pick(worn, full(recipe["paint_roughness"]),
                      recipe["bare_roughness"] + 0.1 * patterns.value_noise(q * 20.0, seed))
        metal = _pick(worn, zeros, ones)
    elif cls == "fabric":
        c0, c1 = (lin(c) for c in recipe["colours"])
        if recipe["pattern"] == "tartan":
            a = patterns.stripes(q, vec([1.0, 0.0, 0.0]), recipe["tartan"], 0.35)
            b = patterns.stripes(q, vec([0.0, 0.7071, 0.7071]), recipe["tartan"], 0.35)
            mix = (a.float() + b.float())[:, None] / 2
        else:
            mix = patterns.checker(q, recipe["weave"]).float()[:, None]
        thread = 0.8 + 0.4 * patterns.value_noise(q * recipe["weave"] * 2, seed)[:, None]
        albedo = (c0 * (1 - mix) + c1 * mix) * thread
        rough = recipe["roughness"] - 0.1 * patterns.value_noise(q * recipe["weave"], seed + 3)
        metal = zeros
    elif cls == "ceramic":
        f1, f2, ident = patterns.voronoi(q * recipe["tiles"], seed)
        grout = (f2 - f1) < 0.08
        ink = patterns.glyph_stripes(q, seed + 9, lines=recipe["lines"], band=(-0.5, 0.3))
        glaze = lin(recipe["glaze"]) * (0.85 + 0.15 * ident)[:, None]
        albedo = _pick(ink, glaze, lin(recipe["decoration"]).expand(n, 3))
        albedo = _pick(grout, albedo, lin(recipe["grout"]).expand(n, 3))
        rough = _pick(grout, full(recipe["roughness"]), full(0.8))
        rim = q[:, 2] > recipe["rim"]
        albedo = _pick(rim, albedo, vec(METAL_F0["gold"]).expand(n, 3))
        rough = _pick(rim, rough, full(0.15))
        metal = _pick(rim, zeros, ones)
    elif cls == PLAIN_CLASS:
        albedo = vec(recipe["albedo_linear"]).expand(n, 3)
        rough, metal = full(float(recipe["roughness"])), full(float(recipe["metallic"]))
    else:
        raise ValueError(f"unknown material class {cls!r}; "
                         f"allowed: {', '.join((*MATERIAL_CLASSES, PLAIN_CLASS))}")
    if "look" in recipe:  # data.parts.look_swap: another class's albedo on this finish's dielectric points
        albedo = _pick(metal > 0, evaluate_material(recipe["look"], q).albedo_linear, albedo)
    if "finish_roughness" in recipe:  # data.parts.matte_finish: the class's look on a matte finish
        rough = _pick(metal > 0, full(float(recipe["finish_roughness"])), rough)  # metal trim keeps its own
    if "roughness_shift" in recipe:  # data.parts variations (gspi.data.procedural.material_parts)
        rough = rough + recipe["roughness_shift"]
    if "texture" in recipe:  # albedo x (1 + a (n - 1/2)), roughness + a/2 (n - 1/2), n a fBm in [0, 1]
        tex = recipe["texture"]
        noise = patterns.fbm(q * tex["frequency"], int(tex["seed"])) - 0.5
        albedo = albedo * (1.0 + tex["amplitude"] * noise)[:, None]
        rough = rough + 0.5 * tex["amplitude"] * noise
    return MaterialSample(albedo.clamp(0.0, 1.0).float(), rough.clamp(0.02, 1.0).float(),
                          metal.float())
