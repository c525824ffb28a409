"""Import glTF/GLB PBR objects into the canonical scene layout (docs/FORMAT.md).

CLI (gspi/cli/data.py):
    gspi-data import.glb=chair.glb out=DIR [preset=small] [data.renderer=pathtraced]
    gspi-data import.glb=objects/ out=DIR       # objects/{train,val,test}/*.glb, or a flat
                                                # folder of *.glb / *.gltf (all -> test)

Each file becomes one scene named after its stem, exactly like a procedural scene: the asset
(gspi.data.assets.gltf) is normalised to the unit frame (bounding-box centre at the origin,
farthest vertex at radius 1), rendered from the canonical lattice (train) and seeded
held-out val/test views with the preset's image size and supersampling
(gspi.data.assets.mesh_render: GT albedo, roughness, metallic, normals, depth, masks and the
split-sum input; `data.renderer=pathtraced` replaces the input by a Mitsuba rendering),
lit by the capture environment, relit under the held-out ones (`data.capture_envs`,
`data.relight_envs`). An asset draws its views and environments from `scene_rng(seed, k, ...)`
like the procedural scenes, with k a stable number of its file name (`asset_stream`), so they do
not depend on the other files or their order. Folders are searched recursively (a `.gltf` sits
in a sub-folder with its textures). A file that cannot be read is skipped and named in one log
line; every other asset is written, with `splits.json`, and the result lists the failures
(`gspi-data` then exits with status 1). When no asset could be read (a file that is not a GLB)
nothing is written, not even `splits.json`: one error line naming the files, exit 2. scene.json's `generator` holds the recipe (its `name`
is the scene's) and `importer: gspi-glb-import`.
"""
from __future__ import annotations

import logging
import time
import zlib
from pathlib import Path

import numpy as np

from eval.common.layout import SPLITS, read_scene
from gspi.data.lattice import fibonacci_hemisphere_lattice, held_out_directions
from gspi.data.procedural.scene_recipe import scene_rng

EXTENSIONS = (".glb", ".gltf")
log = logging.getLogger(__name__)


def glb_sources(src: str | Path) -> dict[str, list[Path]]:
    """split -> asset files (see module docstring)."""
    from eval.common.errors import MissingInputError
    from gspi.data.assets.gltf import GLTFError

    if not str(src).strip():
        raise GLTFError("import.glb is empty: give a .glb/.gltf file or a folder of them")
    src = Path(src)
    if src.is_file():
        if src.suffix.lower() not in EXTENSIONS:
            raise GLTFError(f"{src}: not a .glb or .gltf file")
        return {"test": [src]}
    if not src.is_dir():
        raise MissingInputError(f"{src}: no such file or folder (import.glb)")

    def assets(folder: Path) -> list[Path]:  # sub-folders too: a .gltf sits beside its textures
        return sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in EXTENSIONS)

    if any((src / s).is_dir() for s in SPLITS):
        out = {s: assets(src / s) for s in SPLITS if (src / s).is_dir()}
    else:
        out = {"test": assets(src)}
    files = [p for ps in out.values() for p in ps]
    if not files:
        raise MissingInputError(f"{src}: no .glb/.gltf files (in it, its sub-folders or train/val/test/)")
    stems = [p.stem for p in files]
    dup = sorted({s for s in stems if stems.count(s) > 1})
    if dup:
        raise GLTFError(f"{src}: several assets share the scene names {dup}")
    return out


def asset_stream(path: Path) -> int:
    """The asset's random stream: a stable number of its file name, so that its views and
    environments do not depend on which other files are imported beside it, or their order."""
    return zlib.crc32(path.stem.encode("utf-8")) & 0x7FFFFFFF


def glb_recipe(path: Path, index: int, seed: int, cfg) -> dict:
    """Views and environments of asset scene `index` (the procedural recipe's fields), drawn
    from the asset's own stream (``asset_stream``), not its position in the folder."""
    from gspi.data.env_sets import assign_environments, environment_sets

    stream = asset_stream(path)
    lattice = fibonacci_hemisphere_lattice(
        cfg.lattice["num_views"], min_elevation_deg=cfg.lattice.get("min_elevation_deg", 0.0))
    test_dirs = held_out_directions(cfg.num_test_views, scene_rng(seed, stream, 1), lattice=lattice)
    val_dirs = held_out_directions(cfg.num_val_views, scene_rng(seed, stream, 2),
                                   lattice=np.concatenate([lattice, test_dirs]))
    recipe = {"index": index, "stream": stream, "name": path.stem, "family": "glb", "source": str(path.resolve()),
              "test_directions": test_dirs.tolist(), "val_directions": val_dirs.tolist(),
              "view_seed": int(scene_rng(seed, stream).integers(0, 2**31 - 1))}
    capture, relight = environment_sets(cfg.capture_envs, cfg.relight_envs)
    return {**assign_environments({**recipe, "index": stream}, seed, list(capture), list(relight),
                                  cfg.num_relight_envs), "index": index}


def _mark_empty_views(scene_dir: Path) -> list[str]:
    """Held-out (val/test) views in which nothing of the asset is drawn (a single-sided flat
    asset seen from behind is culled) get ``gt_channels: []`` in scene.json: they have nothing
    to score, and the evaluator skips them. Returns their "split/id"s (also logged)."""
    import dataclasses

    from eval.common.layout import read_view_file, write_scene_json

    scene = read_scene(scene_dir)
    empty = []
    for split in ("val", "test"):
        for k, v in enumerate(scene.views.get(split, [])):
            if not (read_view_file(scene.view_dir(split, v.id), "mask.png") > 0.5).any():
                scene.views[split][k] = dataclasses.replace(v, gt_channels=())
                empty.append(f"{split}/{v.id}")
    if empty:
        log.warning("%s: %d held-out view(s) see nothing of the asset (single-sided faces culled), "
                    "marked gt_channels [] (not scored): %s", scene.name, len(empty), ", ".join(empty))
        write_scene_json(scene)
    return empty


def import_glb(src: str | Path, out_dir: str | Path, cfg, *, seed: int = 0) -> dict:
    """Import every asset of `src` into `out_dir` (see module docstring).

    Args:
        cfg: gspi.data.generate.BenchmarkConfig (sizes, lattice, environments, renderer).
    Returns:
        {"splits": {split: [names]}, "scenes": [per-scene stats]}.
    """
    from eval.relight import prefilter_environment
    from gspi.data.env_sets import environment_sets, make_named_environment
    from eval.common.layout import merge_splits
    from gspi.data.assets.gltf import GLTFError, read_gltf
    from gspi.data.assets.mesh_render import render_mesh_views, unit_frame_mesh
    from gspi.data.assets.pathtrace import retracer
    from gspi.data.procedural.render_scene import generate_scene

    out_dir = Path(out_dir)
    sources = glb_sources(src)
    capture, relight = environment_sets(cfg.capture_envs, cfg.relight_envs)
    env_sources = {**capture, **relight}
    envs, pre, stats = {}, {}, []
    files = [(split, p) for split in SPLITS for p in sources.get(split, [])]
    failed: list[dict] = []
    for index, (split, path) in enumerate(files):
        start = time.perf_counter()
        try:
            asset = read_gltf(path)
            mesh = unit_frame_mesh(asset)
        except (GLTFError, ValueError) as exc:  # one bad asset: named, skipped; the others go on
            if len(files) > 1:  # a single file's error is the command's one line (below)
                log.error("skipped %s: %s", path, exc)
            failed.append({"file": str(path), "error": str(exc)})
            continue
        recipe = glb_recipe(path, index, seed, cfg)
        for name in [recipe["capture_env"], *recipe["relight_envs"]]:
            if name not in envs:
                envs[name] = make_named_environment(name, env_sources[name], cfg.env_height,
                                                    white_radiance=cfg.white_radiance)
                pre[name] = prefilter_environment(envs[name])

        def render(cameras, height, width, env, supersample, mesh=mesh):
            return render_mesh_views(mesh, cameras, height, width, env=env,
                                     supersample=supersample)

        s = generate_scene(
            recipe, out_dir, envs=envs, prefiltered=pre, width=cfg.image_size,
            height=cfg.image_size, supersample=cfg.supersample, lattice=cfg.lattice,
            render=render, retrace=retracer(cfg.renderer, cfg.pathtrace, mesh=mesh),
            relit_retrace=retracer(cfg.relit_renderer, cfg.pathtrace, mesh=mesh, key="data.relit_renderer"),
            extra={"importer": "gspi-glb-import", "importer_version": 1, "seed": seed, "preset": cfg.name,
                   "supersample": cfg.supersample, "lattice": cfg.lattice,
                   "renderer": cfg.renderer, "relit_renderer": cfg.relit_renderer, "ignored": asset.ignored,
                   "unit_frame": {"center": mesh.center.tolist(), "scale": mesh.scale}})
        _mark_empty_views(out_dir / recipe["name"])
        if cfg.point_clouds or cfg.contact_sheets:
            from gspi.data.contact_sheet import write_contact_sheet
            from gspi.data.point_clouds import write_scene_point_cloud

            scene = read_scene(out_dir / recipe["name"])
            if cfg.point_clouds:
                write_scene_point_cloud(scene)
            if cfg.contact_sheets:
                write_contact_sheet(scene)
        stats.append({**s, "split": split, "seconds": time.perf_counter() - start})
        log.info("asset %d/%d: imported %s (%s) in %.1f s (input renderer %s: %.1f s)", index + 1, len(files),
                 s["name"], split, stats[-1]["seconds"], cfg.renderer, s["retrace_seconds"])
    if failed and not stats:  # nothing imported: no splits.json, no folder of ours; one line
        raise GLTFError(f"{src}: no asset could be imported, nothing written: "
                        + "; ".join(f["error"] if f["error"].startswith(f["file"]) else f"{f['file']}: {f['error']}"
                                    for f in failed))
    bad = {f["file"] for f in failed}
    splits = merge_splits(out_dir, {split: [p.stem for p in ps if str(p) not in bad]
                                    for split, ps in sources.items()})
    return {"splits": splits, "scenes": stats, "failed": failed}
