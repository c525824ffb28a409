"""gspi-data: make the procedural PBR benchmark, or import/export the field's dataset layouts.

Examples:
    gspi-data preset=tiny out=data/tiny seed=0      # 7 scenes at 64 px (tests, smoke runs)
    gspi-data preset=small out=data/small seed=0    # 22 scenes at 128 px (the demo)
    gspi-data preset=paper out=data/paper seed=0    # 230 scenes at 512 px (large machines)
    gspi-data preset=controlled_pairs out=data/pairs seed=0  # 18 pairs differing in one property (pairs.json)
    gspi-data preset=tiny out=d seed=1 data.num_train_scenes=2 data.image_size=32
    gspi-data import.src=nerf_synthetic/lego out=data/lego_canonical
    gspi-data export.src=data/tiny/s000_torus_metal out=exports/s000
    gspi-data import.src=TensoIR_Synthetic/lego out=data/tensoir      # layout detected from the files
    gspi-data import.src=data/blender_HDR/teapot_scene001 import.format=stanford_orb out=data/orb
    gspi-data export.src=data/tiny/s000_torus_metal export.format=tensoir out=exports/tir
    gspi-data import.glb=chair.glb out=data/mine preset=small      # glTF/GLB PBR object(s)
    gspi-data preset=small out=d data.relight_envs=polyhaven data.renderer=pathtraced
    gspi-data preset=paper out=data/paper seed=0 device=auto     # render on CUDA when present

`preset=<name>` is an alias of Hydra's config-group override `data=<name>` (conf/data/): Hydra
cannot name a group differently from its folder, so `main` rewrites the argument before Hydra
parses the command line. Config: conf/gspi_data.yaml. Output: `out` is also Hydra's run dir,
so `<out>/.hydra/` records the composed config; the working directory never changes.
Layout of the output: gspi.data.procedural.render_scene (per scene), gspi.data.generate (dataset).

`device=auto|cpu|cuda` (default cpu) is resolved at start-up, whatever the mode (`cuda` without
CUDA: one error naming the key). Procedural generation and the training pool render there
(gspi.data.generate). On the CPU whatever the device: the import and export modes (file
conversion; glb ray casting is trimesh/embree) and `data.renderer=pathtraced`'s input images
(Mitsuba's scalar_rgb variant, gspi.data.assets.pathtrace).
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli

log = logging.getLogger(__name__)


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


def import_layout(imp: DictConfig, out: Path):
    """`import.src` in `import.format` (auto: gspi.data.layouts.detect_format) -> (Scene, format)."""
    from gspi.data.layouts import FORMATS, detect_format
    from gspi.strict_config import ConfigError

    fmt = imp.get("format", "auto")
    if fmt not in ("auto", *FORMATS):
        raise ConfigError(f"import.format={fmt}: must be one of auto, {', '.join(FORMATS)}")
    fmt = detect_format(imp.src) if fmt == "auto" else fmt
    if fmt != "nerf_synthetic" and imp.composite != "black":
        raise ConfigError(f"import.composite={imp.composite}: only the nerf_synthetic format composites")
    if fmt == "nerf_synthetic":
        from gspi.data.layouts.nerf_synthetic import import_nerf_synthetic
        return import_nerf_synthetic(imp.src, out, name=imp.name, composite=imp.composite), fmt
    if fmt == "tensoir":
        from gspi.data.layouts.tensoir import import_tensoir
        return import_tensoir(imp.src, out, name=imp.name, envmaps=imp.get("envmaps")), fmt
    if fmt == "stanford_orb":
        from gspi.data.layouts.stanford_orb import import_stanford_orb
        from gspi.strict_config import check_value
        return import_stanford_orb(imp.src, out, name=imp.name, ground_truth=imp.get("ground_truth"),
                                   resolution=check_value("import.resolution", imp.resolution, int, lo=1)), fmt
    from gspi.data.layouts.nero_glossy import import_nero_glossy
    return import_nero_glossy(imp.src, out, name=imp.name, split=imp.get("split")), fmt


def export_layout(exp: DictConfig, out: Path) -> Path:
    """`export.src` (a canonical scene) written in `export.format` under `out`."""
    from gspi.data.layouts import FORMATS
    from gspi.strict_config import ConfigError

    if exp.format not in FORMATS:
        raise ConfigError(f"export.format={exp.format}: must be one of {', '.join(FORMATS)}")
    if exp.format == "nerf_synthetic":
        from gspi.data.layouts.nerf_synthetic import export_nerf_synthetic
        return export_nerf_synthetic(exp.src, out, bits=int(exp.bits))
    if exp.format == "tensoir":
        from gspi.data.layouts.tensoir import export_tensoir
        return export_tensoir(exp.src, out, bits=int(exp.bits))
    if exp.format == "stanford_orb":
        from gspi.data.layouts.stanford_orb import export_stanford_orb
        return export_stanford_orb(exp.src, out)
    from gspi.data.layouts.nero_glossy import export_nero_glossy
    return export_nero_glossy(exp.src, out)


def run(cfg: DictConfig) -> dict:
    """Execute one gspi-data command; returns a summary dict (also logged)."""
    from gspi.device import resolve_device

    out, mode = Path(cfg.out), command_mode(cfg)
    device = resolve_device(cfg.get("device", "cpu"))  # device=cuda without CUDA fails here
    if device.type != "cpu" and mode != "generate":
        log.info("device=%s: %s runs on the CPU (module docstring)", device, mode)
    if mode == "import_glb":
        from gspi.data.assets.glb_import import import_glb

        stats = import_glb(cfg["import"].glb, out, benchmark_config(cfg), seed=int(cfg.seed))
        result = {"mode": "import_glb", **stats}
        if stats["failed"]:
            log.error("%d of %d assets could not be imported: %s", len(stats["failed"]),
                      len(stats["failed"]) + len(stats["scenes"]), ", ".join(f["file"] for f in stats["failed"]))
        # each asset's line ("asset k/N: ...") was logged as it finished (gspi.data.assets.glb_import)
    elif mode == "import":
        from eval.common.layout import merge_splits

        scene, fmt = import_layout(cfg["import"], out)
        merge_splits(out, {"test": [scene.name]})
        result = {"mode": "import", "format": fmt, "scene": str(scene.root), "gt_channels": list(scene.gt_channels),
                  "views": {s: len(v) for s, v in scene.views.items()}}
        log.info("imported %s (%s) -> %s; ground truth: %s", cfg["import"].src, fmt, scene.root,
                 ", ".join(scene.gt_channels) or "none of albedo, roughness, metallic, relight")
    elif mode == "export":
        folder = export_layout(cfg.export, out)
        result = {"mode": "export", "format": cfg.export.format, "folder": str(folder)}
    else:
        from gspi.data.generate import generate_dataset
        from gspi.strict_config import check_value

        bench = benchmark_config(cfg)
        stats = generate_dataset(out, bench, seed=check_value("seed", cfg.seed, int, lo=0), device=device)
        result = {"mode": "generate", "preset": cfg.data.name, "device": str(device), **stats}
        log.info("generated %d scenes on %s in %.1f s (%.0f rays/s end to end) -> %s",
                 len(stats["scenes"]), device, stats["seconds"], stats["rays_per_s"], out)
        # each scene's line ("scene k/N: ...") was logged as it finished (gspi.data.generate.scene_done)
    return result


def _task(cfg: DictConfig) -> None:
    result = run(cfg)
    if result.get("failed"):  # the good assets are written; the status says one failed
        sys.exit(1)


# paths quoted for Hydra's grammar, stated errors as one line
main = hydra_cli(_task, "gspi_data", path_keys=("out", "import.src", "import.glb", "export.src", "import.envmaps",
                                                "import.ground_truth", "import.split"))


if __name__ == "__main__":
    main()
