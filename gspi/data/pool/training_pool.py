"""The Stage II training pool: many train-only scenes, disjoint from every benchmark scene.

Paper, "Training vs. Inference Dynamics": Stage II trains on GT point clouds of many objects.
The benchmark presets hold 16 training scenes (`small`); this mode writes as many as asked
(`conf/data/stage2_pool.yaml`: 256) and only what `gspi-train` reads:

    <out>/splits.json                 {"train": [every pool scene], "val": [], "test": []}
    <out>/<p0000_family_class>/       scene.json, envmaps/<capture>.exr, train/<000..031>/ (the
                                      32 lattice views), gt_points.npz, complete.json (last)

No val/test views, no relit GT, no contact sheet. Disjoint from the benchmark by construction:
pool scene `i` of seed `s` draws from `SeedSequence([s, POOL_NAMESPACE, i])` (benchmark scenes
use namespace 0, `gspi.data.procedural.scene_recipe.scene_rng`) and is named `p{i:04d}_...` (benchmark
scenes are `s{i:03d}_...`). Shape family and material class cycle jointly, so every one of the
7 x 6 (family, class) pairs occurs once the pool has 42 scenes; the capture environment cycles
through every capture environment; the image size cycles through `image_sizes` (the presets'
resolutions, hence their point densities).

Resumable: a scene is done when its `complete.json` exists (written after everything else); a
rerun skips done scenes and regenerates partial ones from scratch, so a killed run loses at most
the scenes in flight. Deterministic: the same seed and config give the same bytes whatever the
number of workers or interruptions (as `gspi.data.generate`).
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Optional

import numpy as np

from gspi.data.environments import env_names
from gspi.data.procedural.material_parts import PartsConfig, sample_parts, vary_part
from gspi.data.procedural.materials import MATERIAL_CLASSES, mix_materials, sample_material
from gspi.data.procedural.sdf_shapes import FAMILIES, sample_shape

POOL_NAMESPACE = 2          # benchmark scenes: 0 (scene_rng), dataset-level draws: 1 (dataset_rng)
DONE_FILE = "complete.json"


def pool_rng(seed: int, index: int) -> np.random.Generator:
    """Generator of pool scene `index` (a stream no benchmark scene of any seed uses)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), POOL_NAMESPACE, int(index)]))


def pool_scene_name(index: int, family: str, material_class: str) -> str:
    return f"p{index:04d}_{family}_{material_class}"


def mix_rng(seed: int, index: int) -> np.random.Generator:
    """Generator of pool scene `index`'s second material: its own stream, so a pool without
    `data.material_mix` keeps every byte it had before the option existed."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), POOL_NAMESPACE, int(index), 1]))


def parts_rng(seed: int, index: int) -> np.random.Generator:
    """Generator of pool scene `index`'s parts and variations (`data.parts`): a stream of its
    own, so a pool without the option keeps every byte."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), POOL_NAMESPACE, int(index), 2]))


def sample_pool_recipe(seed: int, index: int, *, image_sizes: list[int],
                       material_mix: float = 0.0, parts: Optional[PartsConfig] = None) -> dict:
    """Recipe of pool scene `index` (the benchmark recipe's keys, no held-out views or envs).

    `material_mix` (``data.material_mix``, in [0, 1]): the share of scenes that carry a second
    material class over part of the object (`gspi.data.procedural.materials.mix_materials`); the scene's
    name keeps its first class. `parts` (``data.parts``, `gspi.data.procedural.material_parts`): objects of
    2-4 parts and per-part variations; a scene drawn multi-part is not also mixed.
    """
    family = FAMILIES[index % len(FAMILIES)]
    material_class = MATERIAL_CLASSES[(index // len(FAMILIES)) % len(MATERIAL_CLASSES)]
    rng = pool_rng(seed, index)
    capture = env_names("capture")
    shape = sample_shape(family, rng)  # the draws in this order: shape, material, view seed
    material = sample_material(material_class, rng)
    return {
        "index": int(index), "name": pool_scene_name(index, family, material_class),
        "family": family, "shape": shape,
        "material": _pool_material(seed, index, material, material_mix, parts or PartsConfig()),
        "capture_env": capture[(index // (len(FAMILIES) * len(MATERIAL_CLASSES)) + index) % len(capture)],
        "relight_envs": [], "test_directions": [], "val_directions": [],
        "view_seed": int(rng.integers(0, 2**31 - 1)),
        "image_size": int(image_sizes[index % len(image_sizes)]),
        "pool_namespace": POOL_NAMESPACE,
    }


def _pool_material(seed: int, index: int, material: dict, mix_share: float, parts: PartsConfig) -> dict:
    """The scene's material: multi-part, two-class or one class (with variations when asked)."""
    if not parts.is_default:
        rng = parts_rng(seed, index)
        if rng.uniform() < parts.share:
            return sample_parts(material, parts, rng)
        material = vary_part(material, parts, rng) if parts.varies_parts else material
    return _maybe_mixed(seed, index, material, mix_share)


def _maybe_mixed(seed: int, index: int, material: dict, share: float) -> dict:
    """`material` with a second class for the `share` of scenes drawn to carry one, else itself."""
    rng = mix_rng(seed, index)
    return mix_materials(material, rng) if rng.uniform() < share else material


def pool_recipes(seed: int, num_scenes: int, image_sizes: list[int],
                 indices: Optional[list] = None, material_mix: float = 0.0,
                 parts: Optional[PartsConfig] = None) -> list[dict]:
    """Recipes of pool scenes ``0 .. num_scenes - 1``, or only those in ``indices``.

    ``indices`` (``data.pool_indices``): ``[[start, stop], ...]`` half-open index ranges inside
    ``num_scenes``, e.g. ``[[0, 64], [224, 256]]`` for a training subset and the held-out scenes
    without rendering the 160 between them. Scene ``i`` is the same whichever others are made.
    """
    if num_scenes < 1:
        raise ValueError(f"data.num_train_scenes must be >= 1 for a training pool, got {num_scenes}")
    if not image_sizes or any(int(s) < 8 for s in image_sizes):
        raise ValueError(f"data.image_sizes must be a non-empty list of sizes >= 8, got {image_sizes}")
    if not 0.0 <= material_mix <= 1.0:
        raise ValueError(f"data.material_mix must be in [0, 1], got {material_mix}")
    return [sample_pool_recipe(seed, i, image_sizes=list(image_sizes), material_mix=material_mix,
                               parts=parts) for i in selected_indices(num_scenes, indices)]


def selected_indices(num_scenes: int, indices: Optional[list]) -> list[int]:
    """Sorted pool indices named by ``data.pool_indices`` (all ``num_scenes`` when None)."""
    if indices is None:
        return list(range(num_scenes))
    chosen: set[int] = set()
    for r in indices:
        if len(r) != 2 or not 0 <= int(r[0]) < int(r[1]) <= num_scenes:
            raise ValueError(f"data.pool_indices: {list(r)} is not a [start, stop] range with "
                             f"0 <= start < stop <= data.num_train_scenes ({num_scenes})")
        chosen.update(range(int(r[0]), int(r[1])))
    return sorted(chosen)


def is_complete(scene_dir: Path) -> bool:
    return (scene_dir / DONE_FILE).is_file()


def pending_recipes(out_dir: Path, recipes: list[dict]) -> list[dict]:
    """Recipes whose scene is not complete; partial scene folders are removed."""
    todo = []
    for r in recipes:
        root = out_dir / r["name"]
        if is_complete(root):
            continue
        if root.exists():
            shutil.rmtree(root)
        todo.append(r)
    return todo


def mark_complete(scene_dir: Path, recipe: dict, seed: int) -> None:
    """Written last: the scene's files are all there (no timings: byte-reproducible)."""
    from eval.common.atomic import write_json_atomic

    write_json_atomic(scene_dir / DONE_FILE, {"seed": int(seed), "index": recipe["index"],
                                              "name": recipe["name"]})


def read_pool_done(out_dir: Path) -> list[str]:
    return sorted(p.parent.name for p in Path(out_dir).glob(f"*/{DONE_FILE}"))


def describe(out_dir: Path) -> dict:
    """Counts of a pool folder by family, class, environment and image size (for the docs)."""
    counts: dict[str, dict] = {"family": {}, "class": {}, "capture_env": {}, "image_size": {}}
    for name in read_pool_done(out_dir):
        gen = json.loads((Path(out_dir) / name / "scene.json").read_text())["generator"]
        for key, value in (("family", gen["family"]), ("class", gen["material"]["class"]),
                           ("capture_env", gen["capture_env"]), ("image_size", gen["image_size"])):
            counts[key][str(value)] = counts[key].get(str(value), 0) + 1
    return counts
