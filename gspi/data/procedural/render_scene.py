"""Render and write one procedural scene in the canonical layout (docs/FORMAT.md, eval.common.layout).

`<out>/<scene name>/`:
    scene.json                 cameras (OpenCV) + capture/relight env names + `generator` recipe
    envmaps/<env>.exr          the capture environment and each relighting environment
    train/<000..031>/          the canonical 32-view lattice, in lattice order (Stage II index k)
    val/<v00..>/, test/<t00..>/  held-out views off the lattice (per-scene seeded directions)
        rgb.exr rgb.png albedo.png roughness.png metallic.png normal.exr depth.exr mask.png
    test/<id>/relit_<env>.exr  relit ground truth: `eval.views.relight_view` of the STORED
                               (quantised) maps, read back from disk, under each relight env
    gt_points.npz              GT point cloud of the lattice views (gspi.data.point_clouds)
    contact_sheet.png          preview (gspi.data.contact_sheet)

Per-view conventions are those of `gspi.data.procedural.render_view`. Relit images use the same shader,
the same environment file and the same `view_directions` as the evaluator, so re-rendering
them from the files reproduces them bit for bit (on the CPU; relit images of a dataset made
with `device=cuda` are shaded on the GPU and agree with a CPU re-rendering to float rounding).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from eval.common.colorspace import linear_to_srgb
from eval.common.imageio import read_exr, write_exr
from eval.common.layout import Scene, View, read_view_file, write_material, write_scene_json, \
    write_view_file
from eval.views import relight_view, view_directions
from gspi.data.lattice import cameras_from_directions, lattice_cameras
from gspi.data.procedural.render_view import ViewRender, render_views
from gspi.data.procedural.sdf_shapes import ShapeSDF

VIEW_ID_PREFIX = {"val": "v", "test": "t"}


def scene_views(recipe: dict, *, width: int, height: int, lattice: dict) -> dict[str, list[View]]:
    """Cameras of a scene: train = the canonical lattice, val/test = the recipe's directions."""
    K, w2c = lattice_cameras(width=width, height=height, **lattice)
    views = {"train": [View(f"{k:03d}", "train", K[k], w2c[k]) for k in range(len(K))]}
    for split in ("val", "test"):
        dirs = np.asarray(recipe[f"{split}_directions"], dtype=np.float64).reshape(-1, 3)
        if len(dirs) == 0:
            continue
        Ks, w2cs = cameras_from_directions(dirs, radius=lattice["radius"], fov_deg=lattice["fov_deg"],
                                           width=width, height=height)
        views[split] = [View(f"{VIEW_ID_PREFIX[split]}{k:02d}", split, Ks[k], w2cs[k])
                        for k in range(len(dirs))]
    return views


def write_view(view_dir: Path, r: ViewRender) -> None:
    """Write the eight per-view files of a rendered view (nine with outside_brdf.png)."""
    write_view_file(view_dir, "rgb.exr", r.rgb)
    write_view_file(view_dir, "rgb.png",
                    linear_to_srgb(torch.from_numpy(r.rgb).clamp(0, 1)).numpy())
    write_material(view_dir, "albedo", r.albedo_srgb)
    write_material(view_dir, "roughness", r.roughness)
    write_material(view_dir, "metallic", r.metallic)
    write_view_file(view_dir, "normal.exr", r.normal)
    write_view_file(view_dir, "depth.exr", r.depth)
    write_view_file(view_dir, "mask.png", r.mask.astype(np.float32))
    if r.outside_brdf is not None:  # optional (eval/common/layout.py OPTIONAL_GT_FILES)
        write_view_file(view_dir, "outside_brdf.png", r.outside_brdf.astype(np.float32))


def stored_relight_inputs(scene: Scene, view: View, device: torch.device | str = "cpu"
                          ) -> dict[str, torch.Tensor]:
    """The relighting inputs of a view, read back from its stored files (as the evaluator does),
    on `device`."""
    vdir = scene.view_dir(view.split, view.id)
    t = {name: torch.from_numpy(read_view_file(vdir, f)).to(device) for name, f in
         (("albedo", "albedo.png"), ("roughness", "roughness.png"), ("metallic", "metallic.png"),
          ("normal", "normal.exr"))}
    t["view_dir"] = view_directions(view.K, view.w2c, scene.height, scene.width).to(device)
    return t


def relight_stored_view(scene: Scene, view: View, env, device: torch.device | str = "cpu") -> np.ndarray:
    """`eval.views.relight_view` of the stored maps of `view` under `env`, shaded on `device`
    -> [H, W, 3] float32 (CPU)."""
    t = stored_relight_inputs(scene, view, device)
    out = relight_view(t["albedo"], t["roughness"], t["metallic"], t["normal"], t["view_dir"], env)
    return out.cpu().numpy().astype(np.float32)


def _view_seed(view_seed: int, split: str, k: int) -> int:
    """Jitter seed of view k of a split (independent streams per split and view)."""
    ss = np.random.SeedSequence([int(view_seed), ["train", "val", "test"].index(split), int(k)])
    return int(ss.generate_state(1)[0])


def sdf_renderer(recipe: dict, device: torch.device | str = "cpu"):
    """The procedural scenes' renderer: `render(cameras, height, width, env, supersample)`,
    tracing and shading on `device`."""
    shape = ShapeSDF(recipe["shape"])

    def render(cameras, height, width, env, supersample):
        return render_views(shape, recipe["material"], cameras, height, width, env=env,
                            supersample=supersample, device=device)
    return render


def generate_scene(recipe: dict, out_dir: Path, *, envs: dict[str, torch.Tensor],
                   prefiltered: dict, width: int, height: int, supersample: int,
                   lattice: dict, extra: dict | None = None, render=None,
                   retrace=None, relit_retrace=None, device: torch.device | str = "cpu") -> dict:
    """Render every view of a scene and write it (see module docstring).

    Args:
        recipe: from `gspi.data.procedural.scene_recipe.sample_scene_recipe`.
        out_dir: dataset folder; the scene goes to `out_dir / recipe["name"]`.
        envs: env name -> [h, w, 3] float32 CPU map (written to envmaps/).
        prefiltered: env name -> `eval.relight.PrefilteredEnvironment` of the same map (best
            on `device`).
        width, height: image size; supersample: S (S x S rays per pixel); lattice: kwargs of
            `lattice_cameras` (num_views, radius, fov_deg, min_elevation_deg).
        extra: more metadata for scene.json's `generator` entry.
        render: `render(cameras, height, width, prefiltered env, supersample)` -> ViewRenders
            (default: `sdf_renderer(recipe)`); GT maps and split-sum rgb of every view.
        retrace: optional `retrace(cameras, height, width, env [h, w, 3])` -> one rgb
            [H, W, 3] per camera that replaces the split-sum input (gspi.data.assets.pathtrace);
            maps, masks and relit ground truth stay those of `render`.
        relit_retrace: optional, the same kind of function: renders the test views' relit
            ground truth under each relight environment (`data.relit_renderer=pathtraced`:
            shadows and interreflection) instead of split-sum shading the stored GT maps.
        device: where the default renderer traces and shades and the relit ground truth is
            shaded; files are written from the CPU.
    Returns:
        Stats: {"name", "seconds", "rays", "sdf_evals", "views", "retrace_seconds"}.
    """
    start = time.perf_counter()
    root = Path(out_dir) / recipe["name"]
    views = scene_views(recipe, width=width, height=height, lattice=lattice)
    scene = Scene(root=root, name=recipe["name"], width=width, height=height, views=views,
                  capture_env=recipe["capture_env"], relight_envs=list(recipe["relight_envs"]),
                  extra={"generator": {**(extra or {}), **recipe}})
    write_scene_json(scene)
    for name in [scene.capture_env, *scene.relight_envs]:
        write_exr(scene.envmap_path(name), envs[name].numpy())
    render = render or sdf_renderer(recipe, device)
    todo = [(split, k, view) for split, vs in views.items() for k, view in enumerate(vs)]
    cameras = [(view.K, view.w2c, _view_seed(recipe["view_seed"], split, k))
               for split, k, view in todo]
    renders = render(cameras, height, width, prefiltered[scene.capture_env], supersample)
    retrace_seconds = 0.0
    if retrace is not None:
        t0 = time.perf_counter()
        for r, rgb in zip(renders, retrace(cameras, height, width, envs[scene.capture_env])):
            r.rgb = rgb
        retrace_seconds = time.perf_counter() - t0
    for (split, _, view), r in zip(todo, renders):
        write_view(scene.view_dir(split, view.id), r)
    rays, evals = sum(r.rays for r in renders), sum(r.sdf_evals for r in renders)
    test_views = views.get("test", [])
    test_cameras = [c for (split, _, _), c in zip(todo, cameras) if split == "test"]
    for env_name in scene.relight_envs:
        if relit_retrace is not None:
            relit = relit_retrace(test_cameras, height, width, envs[env_name])
        else:
            relit = [relight_stored_view(scene, view, prefiltered[env_name], device) for view in test_views]
        for view, image in zip(test_views, relit):
            write_exr(scene.view_dir("test", view.id) / f"relit_{env_name}.exr", image)
    return {"name": scene.name, "seconds": time.perf_counter() - start, "rays": rays,
            "sdf_evals": evals, "views": sum(len(v) for v in views.values()),
            "retrace_seconds": retrace_seconds}


def load_environment(path: Path) -> torch.Tensor:
    """[h, w, 3] float32 tensor of an environment EXR."""
    return torch.from_numpy(read_exr(path))
