"""gspi-data: make the procedural PBR benchmark, or import/export NeRF-synthetic scenes.

Examples:
    gspi-data preset=tiny out=data/tiny seed=0      # 7 scenes at 64 px (tests, smoke runs)
    gspi-data preset=small out=data/small seed=0    # 22 scenes at 128 px (the demo)
    gspi-data preset=paper out=data/paper seed=0    # 230 scenes at 512 px (large machines)
    gspi-data preset=tiny out=d seed=1 data.num_train_scenes=2 data.image_size=32
    gspi-data import.src=nerf_synthetic/lego out=data/lego_canonical
    gspi-data export.src=data/tiny/s000_torus_metal out=exports/s000
    gspi-data import.glb=chair.glb out=data/mine preset=small      # glTF/GLB PBR object(s)
    gspi-data preset=small out=d data.relight_envs=polyhaven data.renderer=pathtraced
    gspi-data preset=paper out=data/paper seed=0 device=auto     # render on CUDA when present

`preset=<name>` is an alias of Hydra's config-group override `data=<name>` (conf/data/): Hydra
cannot name a group differently from its folder, so `main` rewrites the argument before Hydra
parses the command line. Config: conf/gspi_data.yaml. Output: `out` is also Hydra's run dir,
so `<out>/.hydra/` records the composed config; the working directory never changes.
Layout of the output: gspi.data.render_scene (per scene), gspi.data.generate (dataset).

`device=auto|cpu|cuda` (default cpu) is resolved at start-up, whatever the mode (`cuda` without
CUDA: one error naming the key). Procedural generation and the training pool render there
(gspi.data.generate). On the CPU whatever the device: the import and export modes (file
conversion; glb ray casting is trimesh/embree) and `data.renderer=pathtraced`'s input images
(Mitsuba's scalar_rgb variant, gspi.data.pathtrace).
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.cli_entry import hydra_cli

log = logging.getLogger(__name__)
PRESET_ALIAS = ("preset=", "data=")


def benchmark_config(cfg: DictConfig):
    """conf `data` group + `lattice` + `threads` -> gspi.data.generate.BenchmarkConfig."""
    from gspi.data.generate import BenchmarkConfig
    from gspi.strict_config import dataclass_from_dict

    data = OmegaConf.to_container(cfg.data, resolve=True)
    # every value checked (names, types, ranges) before anything is written
    return dataclass_from_dict(BenchmarkConfig, {**data, "threads": cfg.threads,
                                                 "lattice": OmegaConf.to_container(cfg.lattice, resolve=True)}, "data")


def command_mode(cfg: DictConfig) -> str:
    """What a gspi-data command line asks for: import_glb | import | export | generate."""
    imp, exp = cfg.get("import"), cfg.get("export")
    if imp is not None and imp.get("glb") is not None:
        return "import_glb"
    if imp is not None and imp.src is not None:
        return "import"
    if exp is not None and exp.src is not None:
        return "export"
    return "generate"


def run(cfg: DictConfig) -> dict:
    """Execute one gspi-data command; returns a summary dict (also logged)."""
    from gspi.device import resolve_device

    out, mode = Path(cfg.out), command_mode(cfg)
    device = resolve_device(cfg.get("device", "cpu"))  # device=cuda without CUDA fails here
    if device.type != "cpu" and mode != "generate":
        log.info("device=%s: %s runs on the CPU (module docstring)", device, mode)
    if mode == "import_glb":
        from gspi.data.glb_import import import_glb

        stats = import_glb(cfg["import"].glb, out, benchmark_config(cfg), seed=int(cfg.seed))
        result = {"mode": "import_glb", **stats}
        if stats["failed"]:
            log.error("%d of %d assets could not be imported: %s", len(stats["failed"]),
                      len(stats["failed"]) + len(stats["scenes"]), ", ".join(f["file"] for f in stats["failed"]))
        for s in stats["scenes"]:
            log.info("imported %s (%s) in %.1f s (input renderer %s: %.1f s)", s["name"],
                     s["split"], s["seconds"], cfg.data.renderer, s["retrace_seconds"])
    elif mode == "import":
        from gspi.data.nerf_synthetic import import_nerf_synthetic
        from gspi.data.generate import merge_splits

        scene = import_nerf_synthetic(cfg["import"].src, out, name=cfg["import"].name,
                                      composite=cfg["import"].composite)
        merge_splits(out, {"test": [scene.name]})
        result = {"mode": "import", "scene": str(scene.root),
                  "views": {s: len(v) for s, v in scene.views.items()}}
    elif mode == "export":
        from gspi.data.nerf_synthetic import export_nerf_synthetic

        folder = export_nerf_synthetic(cfg.export.src, out, bits=int(cfg.export.bits))
        result = {"mode": "export", "folder": str(folder)}
    else:
        from gspi.data.generate import generate_dataset
        from gspi.strict_config import check_value

        bench = benchmark_config(cfg)
        stats = generate_dataset(out, bench, seed=check_value("seed", cfg.seed, int, lo=0), device=device)
        result = {"mode": "generate", "preset": cfg.data.name, "device": str(device), **stats}
        log.info("generated %d scenes on %s in %.1f s (%.0f rays/s end to end) -> %s",
                 len(stats["scenes"]), device, stats["seconds"], stats["rays_per_s"], out)
        for s in stats["scenes"]:
            log.info("scene %s: %.1f s (input renderer %s: %.1f s)", s["name"], s["seconds"],
                     cfg.data.renderer, s["retrace_seconds"])
    return result


def _task(cfg: DictConfig) -> None:
    result = run(cfg)
    if result.get("failed"):  # the good assets are written; the status says one failed
        sys.exit(1)


def alias_preset(argv: list[str]) -> list[str]:
    """Rewrite `preset=X` (and `+preset=X`) to Hydra's group override `data=X`."""
    old, new = PRESET_ALIAS
    return [new + a[len(old):] if a.startswith(old) else
            new + a[len(old) + 1:] if a.startswith("+" + old) else a for a in argv]


# paths quoted for Hydra's grammar, stated errors as one line
main = hydra_cli(_task, "gspi_data", path_keys=("out", "import.src", "import.glb", "export.src"), rewrite=alias_preset)


if __name__ == "__main__":
    main()
