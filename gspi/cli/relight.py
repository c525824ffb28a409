"""gspi-relight: relight a PBR-GS asset under any environment (turntable, stills, animation).

Examples:
    gspi-relight asset=runs/method=gspi/work/s002/pbr_gs.ply env=meadow out=/tmp/relit
    gspi-relight asset=.../pbr_gs.ply env=data/s002/envmaps/neon.exr out=/tmp/relit \\
        exposure_stops=1 env_rotation_deg=90 frames=36 size=384
    gspi-relight asset=... env=sky_morning out=... spin=env     # fixed camera, the lighting turns
    gspi-relight asset=... env=meadow out=... 'views=[[0,20],[90,45]]' frames=0

Writes into ``out``: ``frames/frame_<k>.png`` (the turntable), ``turntable.webp`` (animated,
looping), ``view_<k>.png`` for each of ``views`` and ``relight.json`` (config, environment,
seconds). Shading: ``gspi.relight.shade_asset``. Config: conf/gspi_relight.yaml.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli
from eval.common.errors import MissingInputError

log = logging.getLogger(__name__)
SPINS = ("camera", "env")
ANIMATIONS = ("webp", "none")


def write_animation(frames, path: Path, fps: float) -> Path:
    """Looping animated WebP of uint8 [H, W, 3] frames (Pillow)."""
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(path, format="WEBP", save_all=True, append_images=images[1:], loop=0,
                   duration=int(round(1000 / fps)), quality=80, method=4)
    return path


def _render(asset, env, azimuths, elevations, cfg, *, centre, distance):
    from gspi.relight import orbit_cameras, shade_asset, to_display

    w2c, K = orbit_cameras(azimuths, elevations, radius=distance, target=centre,
                           width=int(cfg.size), height=int(cfg.size), fov_deg=float(cfg.fov_deg))
    shaded = shade_asset(asset, env, w2c, K, int(cfg.size), int(cfg.size), backend=cfg.backend)
    return to_display(shaded, exposure_stops=float(cfg.exposure_stops), tonemap_mode=cfg.tonemap,
                      background=tuple(cfg.background))


def turntable(asset, env_map, cfg, *, centre, distance) -> list:
    """uint8 frames of one turn: the camera orbits (spin=camera) or the environment turns."""
    from eval.relight import prefilter_environment
    from gspi.relight import rotate_environment

    n = int(cfg.frames)
    steps = [360.0 * k / n for k in range(n)]
    if cfg.spin == "camera":
        pre = prefilter_environment(env_map)
        return list(_render(asset, pre, steps, [float(cfg.elevation_deg)] * n, cfg,
                            centre=centre, distance=distance))
    frames = []
    for deg in steps:  # one prefilter per frame: the lighting itself changes
        pre = prefilter_environment(rotate_environment(env_map, deg))
        frames += list(_render(asset, pre, [0.0], [float(cfg.elevation_deg)], cfg, centre=centre,
                               distance=distance))
    return frames


def run(cfg: DictConfig) -> dict:
    """Relights ``cfg.asset`` into ``cfg.out``; returns relight.json's content."""
    import torch
    from PIL import Image

    from eval.common.atomic import write_json_atomic
    from eval.relight import prefilter_environment
    from gspi.gaussians.ply import read_ply
    from gspi.relight import framing, load_environment, rotate_environment

    if cfg.spin not in SPINS:
        raise ValueError(f"spin={cfg.spin!r}; allowed: {', '.join(SPINS)}")
    if cfg.animation not in ANIMATIONS:
        raise ValueError(f"animation={cfg.animation!r}; allowed: {', '.join(ANIMATIONS)}")
    t0 = time.perf_counter()
    torch.set_num_threads(int(cfg.threads))
    asset_path, out = Path(cfg.asset), Path(cfg.out)
    if not asset_path.is_file():
        raise MissingInputError(f"{asset_path}: asset file not found (asset= takes GS-PI's pbr_gs.ply)")
    env_map = rotate_environment(load_environment(cfg.env, height=int(cfg.env_height)),
                                 float(cfg.env_rotation_deg))  # a bad env= fails before the asset is read
    asset = read_ply(asset_path)
    if not asset.has_pbr:
        from gspi.relight import NotPBRAssetError

        raise NotPBRAssetError(f"{asset_path}: has no PBR attributes (albedo_0..2, roughness, metallic): "
                               "relight GS-PI's pbr_gs.ply, not a plain 2DGS/3DGS asset")
    centre, distance = framing(asset, float(cfg.fov_deg))
    written = {"frames": [], "views": [], "animation": None}
    if int(cfg.frames) > 0:
        frames = turntable(asset, env_map, cfg, centre=centre, distance=distance)
        for k, frame in enumerate(frames):
            path = out / "frames" / f"frame_{k:03d}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(frame).save(path)
            written["frames"].append(str(path))
        if cfg.animation == "webp":
            written["animation"] = str(write_animation(frames, out / "turntable.webp", float(cfg.fps)))
    stills = [tuple(map(float, v)) for v in cfg.views]
    if stills:
        images = _render(asset, prefilter_environment(env_map), [a for a, _ in stills],
                         [e for _, e in stills], cfg, centre=centre, distance=distance)
        for k, image in enumerate(images):
            path = out / f"view_{k}.png"
            out.mkdir(parents=True, exist_ok=True)
            Image.fromarray(image).save(path)
            written["views"].append(str(path))
    record = {"asset": str(asset_path.resolve()), "env": str(cfg.env),
              "num_gaussians": int(asset.means.shape[0]),
              "config": OmegaConf.to_container(cfg, resolve=True), **written,
              "seconds": time.perf_counter() - t0}
    write_json_atomic(out / "relight.json", record)
    log.info("%s under %s: %d frames, %d stills in %.1f s -> %s", asset_path.name, cfg.env,
             len(written["frames"]), len(written["views"]), record["seconds"], out)
    return record


main = hydra_cli(run, "gspi_relight", path_keys=("asset", "env", "out"))  # paths quoted, stated errors as one line


if __name__ == "__main__":
    main()
