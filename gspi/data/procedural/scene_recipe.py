"""Random scene recipes of the procedural benchmark: everything a scene is, decided by seed.

A recipe is a JSON-serialisable dict (stored in `scene.json` under `generator`):

    {"index", "name", "family", "shape": <sdf_shapes recipe>, "material": <materials recipe>,
     "capture_env", "relight_envs": [...], "test_directions": [[3]...], "val_directions": [...],
     "view_seed": int}

Scene `index` of dataset `seed` draws from `numpy.random.default_rng(SeedSequence([seed, index]))`,
so a scene does not depend on how many scenes are generated. Shape families and material
classes cycle through seeded permutations (offset by the index), so every family and every
class occurs once the dataset has 7 (resp. 6) scenes.
"""
from __future__ import annotations

import numpy as np

from gspi.data.environments import env_names
from gspi.data.lattice import fibonacci_hemisphere_lattice, held_out_directions
from gspi.data.procedural.materials import MATERIAL_CLASSES, sample_material
from gspi.data.procedural.sdf_shapes import FAMILIES, sample_shape


def scene_rng(seed: int, index: int, stream: int = 0) -> np.random.Generator:
    """Independent generator for (dataset seed, scene index, stream)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), 0, int(index), int(stream)]))


def dataset_rng(seed: int, purpose: int) -> np.random.Generator:
    """Dataset-level generator (0: family/class order, 1: split assignment)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), 1, int(purpose)]))


def scene_name(index: int, family: str, material_class: str) -> str:
    return f"s{index:03d}_{family}_{material_class}"


def sample_scene_recipe(seed: int, index: int, *, num_test_views: int, num_val_views: int,
                        num_relight_envs: int, num_lattice_views: int = 32,
                        min_elevation_deg: float = 0.0) -> dict:
    """The recipe of scene `index` of the dataset with `seed` (see module docstring)."""
    order = dataset_rng(seed, 0)
    families = [FAMILIES[i] for i in order.permutation(len(FAMILIES))]
    classes = [MATERIAL_CLASSES[i] for i in order.permutation(len(MATERIAL_CLASSES))]
    family = families[index % len(families)]
    material_class = classes[(index + index // len(classes)) % len(classes)]
    rng = scene_rng(seed, index)
    shape = sample_shape(family, rng)
    material = sample_material(material_class, rng)
    capture = env_names("capture")
    heldout = env_names("heldout")
    if not 0 <= num_relight_envs <= len(heldout):
        raise ValueError(f"num_relight_envs must be in [0, {len(heldout)}], got {num_relight_envs}")
    relight = sorted(rng.choice(len(heldout), size=num_relight_envs, replace=False).tolist())
    test_dirs, val_dirs = held_out_view_directions(
        scene_rng(seed, index, 1), scene_rng(seed, index, 2), num_test_views=num_test_views,
        num_val_views=num_val_views, num_lattice_views=num_lattice_views,
        min_elevation_deg=min_elevation_deg)
    return {
        "index": int(index), "name": scene_name(index, family, material_class),
        "family": family, "shape": shape, "material": material,
        "capture_env": capture[int(rng.integers(0, len(capture)))],
        "relight_envs": [heldout[i] for i in relight],
        "test_directions": test_dirs.tolist(), "val_directions": val_dirs.tolist(),
        "view_seed": int(rng.integers(0, 2**31 - 1)),
    }


def held_out_view_directions(test_rng: np.random.Generator, val_rng: np.random.Generator, *,
                             num_test_views: int, num_val_views: int, num_lattice_views: int = 32,
                             min_elevation_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A scene's test directions [T, 3], then its val directions [V, 3], each off the lattice
    (and val off the test views), drawn from their own generators."""
    lattice = fibonacci_hemisphere_lattice(num_lattice_views, min_elevation_deg=min_elevation_deg)
    test_dirs = held_out_directions(num_test_views, test_rng, lattice=lattice)
    val_dirs = held_out_directions(num_val_views, val_rng, lattice=np.concatenate([lattice, test_dirs]))
    return test_dirs, val_dirs


def assign_splits(names: list[str], seed: int, *, num_train: int, num_val: int, num_test: int,
                  groups: list[tuple] | None = None) -> dict[str, list[str]]:
    """Seeded assignment of scene names to {"train", "val", "test"} (each list sorted).

    Scenes are visited in a seeded random order; with `groups` (e.g. (shape family, material
    class) per scene) the order is then rebuilt greedily, each step taking the first remaining
    scene whose groups are least represented so far (sum of counts), and dealt to test, then
    val, then train: held-out scenes cover as many different groups as possible.
    """
    if len(names) != num_train + num_val + num_test:
        raise ValueError(f"{len(names)} scenes for {num_train}+{num_val}+{num_test} split slots")
    perm = dataset_rng(seed, 1).permutation(len(names)).tolist()
    if groups is not None:
        counts: dict = {}
        order = []
        while perm:
            best = min(perm, key=lambda i: sum(counts.get((k, g), 0)
                                               for k, g in enumerate(groups[i])))
            perm.remove(best)
            order.append(best)
            for k, g in enumerate(groups[best]):
                counts[(k, g)] = counts.get((k, g), 0) + 1
        perm = order
    picked = [names[i] for i in perm]
    return {"test": sorted(picked[:num_test]),
            "val": sorted(picked[num_test:num_test + num_val]),
            "train": sorted(picked[num_test + num_val:])}
