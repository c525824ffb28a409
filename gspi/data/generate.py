"""Generate the procedural PBR benchmark: scenes, splits, GT point clouds, contact sheets.

`generate_dataset(out_dir, config)` writes

    <out>/splits.json           {"train", "val", "test"}: scene names, assigned by seed
    <out>/<scene>/...           one scene folder per scene (gspi.data.procedural.render_scene)

Determinism: the same seed and config give byte-identical files (images, EXRs, JSON, npz),
provided torch runs with the same thread count (`threads`, default 1: CPU reductions and
matmuls may round differently with another count). Timings are returned, never written
into the dataset, so they cannot break byte-identity.

Parallelism: `workers` > 1 renders scenes in that many processes (each with `threads`
torch threads); results do not depend on the assignment of scenes to workers.

Device (`generate_dataset(..., device=)`, gspi-data's `device=auto|cpu|cuda`): scenes are traced
and shaded there, environments prefiltered there, relit ground truth shaded there; the maps
come back to the CPU at the write. With `workers` > 1 every worker process renders on that same
device (spawned processes, one CUDA context each); the scene-to-worker assignment still does
not matter. CPU (the default): the code path of before, byte-identical files. CUDA: not
byte-identical to the CPU (float rounding; atomic adds in the per-pixel sums make repeated CUDA
runs differ in the last bits too), and scene.json's `generator` records the device.
"""
from __future__ import annotations

import concurrent.futures
import logging
import multiprocessing
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Optional

import torch

from eval.common.layout import read_scene
from eval.common.atomic import write_json_atomic
from gspi.data.contact_sheet import write_contact_sheet
from gspi.data.environments import env_names
from gspi.data.lattice import CANONICAL_LATTICE
from gspi.data.point_clouds import write_scene_point_cloud
from gspi.data.procedural.render_scene import generate_scene, load_environment
from gspi.data.procedural.scene_recipe import assign_splits, sample_scene_recipe

GENERATOR_NAME = "gspi-procedural"
log = logging.getLogger(__name__)
GENERATOR_VERSION = 1


@dataclass(kw_only=True)
class BenchmarkConfig:
    """Sizes of a benchmark preset (conf/data/<preset>.yaml) plus the fixed view lattice."""

    name: str = "custom"                      # preset name, recorded in scene.json
    num_train_scenes: int = 4
    num_val_scenes: int = 1
    num_test_scenes: int = 2
    image_size: int = 64                      # square images, pixels
    supersample: int = 2                      # S: S x S jittered rays per pixel
    env_height: int = 64                      # lat-long rows (width = 2 x rows)
    num_test_views: int = 8                   # held-out views per scene (off the lattice)
    num_val_views: int = 2
    num_relight_envs: int = 3                 # held-out environments per scene (of 6)
    white_radiance: float = 1.0               # exposure: white diffuse at the brightest normal
    point_clouds: bool = True                 # write gt_points.npz
    contact_sheets: bool = True               # write contact_sheet.png
    threads: int = 1                          # torch threads per process
    workers: int = 1                          # scene-parallel processes
    only_splits: Optional[list] = None        # e.g. ["test"]: generate only those splits' scenes
    training_pool: bool = False               # train-only pool scenes (gspi.data.pool.training_pool)
    image_sizes: Optional[list] = None        # training pool: sizes cycled over scenes
    pool_indices: Optional[list] = None       # training pool: only these [start, stop) index ranges
    material_mix: float = 0.0                 # training pool: share of two-class scenes (issue 24)
    parts: dict = field(default_factory=dict) # training pool: multi-part objects (gspi.data.procedural.material_parts)
    controlled_pairs: Optional[dict] = None   # set: scenes in pairs differing in one property (gspi.data.controlled_pairs)
    capture_envs: Any = "procedural"          # procedural | polyhaven | [names or EXR paths]
    relight_envs: Any = "procedural"          # (gspi.data.env_sets; disjoint from capture_envs)
    renderer: str = "splitsum"                # input views: splitsum | pathtraced
    relit_renderer: str = "splitsum"          # relit GT of the test views: splitsum | pathtraced
    pathtrace: dict = field(default_factory=dict)  # gspi.data.assets.pathtrace.PathTraceConfig kwargs
    lattice: dict = field(default_factory=lambda: dict(CANONICAL_LATTICE))

    # Allowed values, checked by gspi.strict_config when gspi-data starts (inclusive; None = open).
    RANGES: ClassVar[dict] = {
        "num_train_scenes": (0, None), "num_val_scenes": (0, None), "num_test_scenes": (0, None),
        "image_size": (8, 8192), "supersample": (1, 16), "env_height": (4, 8192),
        "num_test_views": (0, None), "num_val_views": (0, None), "num_relight_envs": (0, 6),
        "white_radiance": (1e-6, None), "threads": (1, 1024), "workers": (1, 1024),
        "material_mix": (0.0, 1.0)}

    @property
    def num_scenes(self) -> int:
        return self.num_train_scenes + self.num_val_scenes + self.num_test_scenes


def scene_recipes(seed: int, cfg: BenchmarkConfig) -> list[dict]:
    """Recipes of every scene; non-default environment sets only change their environments."""
    from gspi.data.env_sets import assign_environments, environment_sets, is_default

    default_envs = is_default(cfg.capture_envs, cfg.relight_envs)
    # Same draws as the default dataset (views, jitter seeds), whatever the environment sets.
    num_drawn = cfg.num_relight_envs if default_envs else min(cfg.num_relight_envs,
                                                              len(env_names("heldout")))
    recipes = [sample_scene_recipe(seed, i, num_test_views=cfg.num_test_views,
                                   num_val_views=cfg.num_val_views,
                                   num_relight_envs=num_drawn,
                                   num_lattice_views=cfg.lattice["num_views"],
                                   min_elevation_deg=cfg.lattice.get("min_elevation_deg", 0.0))
               for i in range(cfg.num_scenes)]
    if default_envs:
        return recipes
    capture, relight = environment_sets(cfg.capture_envs, cfg.relight_envs)
    capture = None if is_default(cfg.capture_envs) else list(capture)
    relight = None if is_default(cfg.relight_envs) else list(relight)
    return [assign_environments(r, seed, capture, relight, cfg.num_relight_envs) for r in recipes]


_WORKER: dict = {}


def _init_worker(cfg_dict: dict, env_paths: dict[str, str], device: str = "cpu") -> None:
    """Per-process state: thread count, device and the prefiltered environments (built lazily)."""
    torch.set_num_threads(int(cfg_dict["threads"]))
    _WORKER.clear()
    _WORKER.update(cfg=BenchmarkConfig(**cfg_dict), env_paths=env_paths, envs={}, pre={},
                   device=torch.device(device))


def _environment(name: str):
    """(CPU map written into each scene, its prefiltered form on the worker's device)."""
    from eval.relight import prefilter_environment

    if name not in _WORKER["envs"]:
        env = load_environment(Path(_WORKER["env_paths"][name]))
        _WORKER["envs"][name] = env
        _WORKER["pre"][name] = prefilter_environment(env.to(_WORKER["device"]))
    return _WORKER["envs"][name], _WORKER["pre"][name]


def _make_scene(recipe: dict, out_dir: str, seed: int) -> dict:
    cfg: BenchmarkConfig = _WORKER["cfg"]
    device: torch.device = _WORKER["device"]
    names = [recipe["capture_env"], *recipe["relight_envs"]]
    envs, pre = {}, {}
    for n in names:
        envs[n], pre[n] = _environment(n)
    from gspi.data.assets.pathtrace import retracer

    extra = {"name": GENERATOR_NAME, "version": GENERATOR_VERSION, "seed": seed,
             "preset": cfg.name, "supersample": cfg.supersample, "lattice": cfg.lattice}
    if cfg.renderer != "splitsum":  # recorded only when not the default (byte-identity)
        extra |= {"renderer": cfg.renderer, "pathtrace": dict(cfg.pathtrace)}
    if cfg.relit_renderer != "splitsum":
        extra |= {"relit_renderer": cfg.relit_renderer, "pathtrace": dict(cfg.pathtrace)}
    if device.type != "cpu":  # likewise: CPU datasets stay byte-identical to those of before
        extra["device"] = device.type
    size = int(recipe.get("image_size", cfg.image_size))
    stats = generate_scene(recipe, Path(out_dir), envs=envs, prefiltered=pre,
                           width=size, height=size,
                           supersample=cfg.supersample, lattice=cfg.lattice, extra=extra,
                           retrace=retracer(cfg.renderer, cfg.pathtrace, recipe=recipe),
                           relit_retrace=retracer(cfg.relit_renderer, cfg.pathtrace, recipe=recipe,
                                                  key="data.relit_renderer"),
                           device=device)
    t0 = time.perf_counter()
    scene = read_scene(Path(out_dir) / recipe["name"])
    if cfg.point_clouds:
        write_scene_point_cloud(scene)
    if cfg.contact_sheets:
        write_contact_sheet(scene)
    if cfg.training_pool:
        from gspi.data.pool.training_pool import mark_complete

        mark_complete(scene.root, recipe, seed)
    stats["seconds"] += time.perf_counter() - t0
    return stats


def write_environments(env_dir: Path, names: list[str], cfg: BenchmarkConfig) -> dict[str, str]:
    """Make each named environment once into `env_dir` (a scratch folder); name -> path.

    Sources follow `cfg.capture_envs` / `cfg.relight_envs` (gspi.data.env_sets)."""
    from eval.common.imageio import write_exr
    from gspi.data.env_sets import environment_sets, make_named_environment

    capture, relight = environment_sets(cfg.capture_envs, cfg.relight_envs)
    sources = {**capture, **relight}
    paths = {}
    for name in names:
        path = env_dir / f"{name}.exr"
        write_exr(path, make_named_environment(name, sources.get(name, "procedural"),
                                               cfg.env_height,
                                               white_radiance=cfg.white_radiance).numpy())
        paths[name] = str(path)
    return paths


def generate_dataset(out_dir: str | Path, cfg: BenchmarkConfig, *, seed: int,
                     scratch_dir: str | Path | None = None,
                     device: torch.device | str = "cpu") -> dict:
    """Write the whole benchmark (see module docstring).

    Args:
        out_dir: dataset folder (created).
        cfg: sizes. seed: dataset seed (scenes, splits, views, jitter).
        scratch_dir: where the shared environment EXRs are rendered before being copied into
            each scene (default `<out>/.cache`, removed at the end).
        device: where scenes render (module docstring); resolved by the caller
            (gspi.device.resolve_device).
    Returns:
        {"out_dir", "splits", "scenes": [per-scene stats], "seconds", "rays", "rays_per_s",
         "env_seconds"}; with ``cfg.training_pool`` also "skipped" (scenes already complete).
    """
    start = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # splits.json is the dataset's record, written last: remove an earlier one first, so a killed
    # regeneration never leaves old splits beside new scenes (docs/RELIABILITY.md)
    (out_dir / "splits.json").unlink(missing_ok=True)
    if cfg.training_pool:
        return generate_training_pool(out_dir, cfg, seed=seed, scratch_dir=scratch_dir, device=device)
    if cfg.controlled_pairs is not None:
        return generate_controlled_pairs(out_dir, cfg, seed=seed, scratch_dir=scratch_dir, device=device)
    recipes = scene_recipes(seed, cfg)
    splits = assign_splits([r["name"] for r in recipes], seed, num_train=cfg.num_train_scenes,
                           num_val=cfg.num_val_scenes, num_test=cfg.num_test_scenes,
                           groups=[(r["family"], r["material"]["class"]) for r in recipes])
    if cfg.only_splits:  # same scenes and names as the full dataset, fewer of them (make demo)
        unknown = sorted(set(cfg.only_splits) - set(splits))
        if unknown:
            raise ValueError(f"only_splits: unknown splits {unknown} (known: {sorted(splits)})")
        splits = {k: (v if k in cfg.only_splits else []) for k, v in splits.items()}
        keep = {n for v in splits.values() for n in v}
        recipes = [r for r in recipes if r["name"] in keep]
    stats, env_seconds = _render_recipes(out_dir, recipes, cfg, seed=seed, scratch_dir=scratch_dir,
                                         device=device)
    write_json_atomic(out_dir / "splits.json", splits)
    return _summary(out_dir, splits, stats, start, env_seconds)


def generate_training_pool(out_dir: Path, cfg: BenchmarkConfig, *, seed: int,
                           scratch_dir: str | Path | None = None,
                           device: torch.device | str = "cpu") -> dict:
    """The Stage II training pool (gspi.data.pool.training_pool): resumes, skips complete scenes."""
    from gspi.data.env_sets import environment_sets, is_default
    from gspi.data.procedural.material_parts import PartsConfig
    from gspi.data.pool.training_pool import pending_recipes, pool_recipes, read_pool_done

    start = time.perf_counter()
    if cfg.only_splits or cfg.num_val_scenes or cfg.num_test_scenes:
        raise ValueError("a training pool has train scenes only: set data.num_val_scenes=0, "
                         "data.num_test_scenes=0 and no data.only_splits")
    recipes = pool_recipes(seed, cfg.num_train_scenes, list(cfg.image_sizes or [cfg.image_size]),
                           cfg.pool_indices, cfg.material_mix, PartsConfig.from_mapping(cfg.parts))
    if not is_default(cfg.capture_envs):  # e.g. polyhaven: cycle through that capture set
        names = sorted(environment_sets(cfg.capture_envs, cfg.relight_envs)[0])
        recipes = [{**r, "capture_env": names[r["index"] % len(names)]} for r in recipes]
    todo = pending_recipes(out_dir, recipes)
    stats, env_seconds = _render_recipes(out_dir, todo, cfg, seed=seed, scratch_dir=scratch_dir,
                                         device=device)
    done = set(read_pool_done(out_dir))
    splits = {"train": sorted(r["name"] for r in recipes if r["name"] in done), "val": [], "test": []}
    write_json_atomic(out_dir / "splits.json", splits)
    return {**_summary(out_dir, splits, stats, start, env_seconds), "skipped": len(recipes) - len(todo)}


def generate_controlled_pairs(out_dir: Path, cfg: BenchmarkConfig, *, seed: int,
                              scratch_dir: str | Path | None = None,
                              device: torch.device | str = "cpu") -> dict:
    """Pairs of test scenes that differ in one property, and their manifest (gspi.data.controlled_pairs)."""
    from gspi.data.controlled_pairs import ControlledPairsConfig, controlled_pairs, write_manifest
    from gspi.data.env_sets import is_default

    if cfg.training_pool or cfg.only_splits or cfg.num_train_scenes or cfg.num_val_scenes or cfg.num_test_scenes:
        raise ValueError("controlled pairs make test scenes only, as many as data.controlled_pairs asks (kinds x "
                         "families x colours pairs): set data.num_train_scenes, num_val_scenes and num_test_scenes "
                         "to 0, no data.only_splits and no data.training_pool")
    if not is_default(cfg.capture_envs, cfg.relight_envs):
        raise ValueError("controlled pairs use the procedural environments only (data.capture_envs and "
                         "data.relight_envs: procedural)")
    start = time.perf_counter()
    entries, recipes = controlled_pairs(seed, ControlledPairsConfig.from_mapping(cfg.controlled_pairs),
                                        num_test_views=cfg.num_test_views, num_val_views=cfg.num_val_views,
                                        num_relight_envs=cfg.num_relight_envs, lattice=cfg.lattice)
    stats, env_seconds = _render_recipes(out_dir, recipes, cfg, seed=seed, scratch_dir=scratch_dir,
                                         device=device)
    write_manifest(out_dir, seed, entries)
    splits = {"train": [], "val": [], "test": sorted(r["name"] for r in recipes)}
    write_json_atomic(out_dir / "splits.json", splits)
    return _summary(out_dir, splits, stats, start, env_seconds)


def _summary(out_dir: Path, splits: dict, stats: list[dict], start: float, env_seconds: float) -> dict:
    rays = sum(s["rays"] for s in stats)
    return {"out_dir": str(out_dir), "splits": splits, "scenes": stats,
            "seconds": time.perf_counter() - start, "env_seconds": env_seconds, "rays": rays,
            "rays_per_s": rays / max(sum(s["seconds"] for s in stats), 1e-9)}


def scene_done(index: int, total: int, stats: dict, cfg: BenchmarkConfig) -> dict:
    """Logs the progress line of a finished scene (``scene 3/22: <name> in 4.1 s ...``); returns ``stats``."""
    log.info("scene %d/%d: %s in %.1f s (input renderer %s: %.1f s)", index, total, stats["name"],
             stats["seconds"], cfg.renderer, stats.get("retrace_seconds", 0.0))
    return stats


def _render_recipes(out_dir: Path, recipes: list[dict], cfg: BenchmarkConfig, *, seed: int,
                    scratch_dir: str | Path | None, device: torch.device | str = "cpu"
                    ) -> tuple[list[dict], float]:
    """Render every recipe's scene (in `cfg.workers` processes, all on `device`);
    (per-scene stats, env seconds)."""
    import shutil

    start = time.perf_counter()
    scratch = Path(scratch_dir) if scratch_dir is not None else out_dir / ".cache"
    needed = sorted({n for r in recipes for n in [r["capture_env"], *r["relight_envs"]]})
    threads = torch.get_num_threads()
    torch.set_num_threads(int(cfg.threads))
    try:
        env_paths = write_environments(scratch, needed, cfg)
        env_seconds = time.perf_counter() - start
        cfg_dict, device_name = asdict(cfg), str(torch.device(device))
        if cfg.workers > 1:
            ctx = multiprocessing.get_context("spawn")
            with concurrent.futures.ProcessPoolExecutor(
                    cfg.workers, mp_context=ctx, initializer=_init_worker,
                    initargs=(cfg_dict, env_paths, device_name)) as pool:
                stats = [scene_done(k, len(recipes), s, cfg) for k, s in enumerate(
                    pool.map(_make_scene, recipes, [str(out_dir)] * len(recipes), [seed] * len(recipes)), 1)]
        else:
            _init_worker(cfg_dict, env_paths, device_name)
            stats = [scene_done(k, len(recipes), _make_scene(r, str(out_dir), seed), cfg)
                     for k, r in enumerate(recipes, 1)]
    finally:
        torch.set_num_threads(threads)
        _WORKER.clear()
        if scratch_dir is None:
            shutil.rmtree(scratch, ignore_errors=True)
    return stats, env_seconds
