"""Stage I of every asset of a reconstructed pool, kept beside the asset: what a run reads the light
in, for Stage II's light condition read as a run reads it (``stage2.data.light_geometry=asset``,
``gspi.stage2.light_condition.asset_views``; no stage imports another, so Stage I's cloud and
lattice renders travel as files).

    <pool>/<scene>/asset/stage1/points.npz    Stage I's cloud (gspi.point_cloud.PointCloud)
    <pool>/<scene>/asset/stage1/renders.npz   its lattice renders (gspi.gaussians.lattice_render.LatticeRenders)

Stage I at the scene's image size with ``gspi.stage1``'s defaults, as ``gspi-run`` runs it.
Resumable: a scene whose two files exist is skipped (renders written last).

    python -m gspi.stage1.pool_clouds RPOOL
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

log = logging.getLogger(__name__)

from gspi.data.pool.asset_conditions import ASSET_STAGE1_POINTS, ASSET_STAGE1_RENDERS


def write_asset_stage1(scene_dir: Path) -> Path:
    """Stage I of ``scene_dir/asset/point_cloud.ply`` written to ``scene_dir/asset/stage1/``."""
    from eval.common.layout import read_scene
    from gspi.gaussians.ply import read_ply
    from gspi.stage1.config import Stage1Config
    from gspi.stage1.extract import extract_point_cloud

    points, renders, _ = extract_point_cloud(read_ply(scene_dir / "asset" / "point_cloud.ply"),
                                             Stage1Config(image_size=read_scene(scene_dir).width))
    points.save(scene_dir / ASSET_STAGE1_POINTS)
    renders.save(scene_dir / ASSET_STAGE1_RENDERS)  # last: the pair is complete
    return scene_dir / ASSET_STAGE1_RENDERS.parent


def write_pool_stage1(pool: Path) -> int:
    """``write_asset_stage1`` for every scene of ``pool`` with an asset and no Stage I yet; the count written."""
    scenes = sorted(p.parent.parent for p in Path(pool).glob("*/asset/point_cloud.ply"))
    if not scenes:
        raise ValueError(f"{pool}: no scene with asset/point_cloud.ply (a reconstructed pool: "
                         "python -m gspi.recon.reconstructed_pool)")
    todo = [s for s in scenes if not (s / ASSET_STAGE1_RENDERS).is_file()]
    log.info("%s: %d scenes, %d to run Stage I on", pool, len(scenes), len(todo))
    for k, scene in enumerate(todo, 1):
        t0 = time.perf_counter()
        write_asset_stage1(scene)
        log.info("[%d/%d] %s: %.1f s", k, len(todo), scene.name, time.perf_counter() - t0)
    return len(todo)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pool", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    import torch

    torch.set_num_threads(1)
    write_pool_stage1(args.pool)


if __name__ == "__main__":
    main()
