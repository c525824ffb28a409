"""gspi-extract: Stage I, a 2DGS asset -> filtered, source-anchored point cloud.

Examples:
    gspi-extract asset=runs/recon/s002/point_cloud.ply out=runs/extract/s002
    gspi-extract asset=runs/recon/s002/point_cloud.ply out=runs/extract/s002 \\
        scene=data/small/s002_multipart_ceramic          # + distances to the GT surface per filter
    gspi-extract asset=... out=/tmp/x stage1=tiny        # 48 px, seconds
    gspi-extract asset=... out=... stage1.outliers.enabled=false stage1.depth_consensus.tolerance_px=2
    gspi-extract asset=... out=... stage1.max_points=20000   # seeded subsample (CPU-scale knob)

Renders the asset's 32 canonical lattice views, unprojects foreground pixels with the median
depth and applies the three filters (gspi/stage1/). Writes into ``out`` (also Hydra's run dir,
with ``.hydra/``; the working directory never changes):

* ``points.npz``: ``gspi.point_cloud.PointCloud`` (xyz, source view, pixel, linear RGB,
  image size);
* ``stage1.json``: the config, the per-filter report (count, removed and, with ``scene=``, the
  distances of kept and removed points to the scene's ``gt_points.npz`` in world units and pixel
  footprints, with the GT cloud's own spacing as the floor), counts and seconds.

Config: conf/gspi_extract.yaml, conf/stage1/{default,paper,tiny}.yaml.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli
from eval.common.errors import MissingInputError

log = logging.getLogger(__name__)
# Absolute: a relative config_path resolves as a Python package under console scripts.


def read_reference(scene_dir: Path):
    """(xyz [R, 3] float64, view [R] int64) of ``<scene_dir>/gt_points.npz``."""
    import numpy as np

    path = scene_dir / "gt_points.npz"
    if not path.is_file():
        raise MissingInputError(f"{path}: missing (scene= must be a canonical scene folder generated with "
                                "point clouds; docs/FORMAT.md)")
    with np.load(path) as npz:
        if "xyz" not in npz or "view" not in npz:
            raise ValueError(f"{path}: no 'xyz' / 'view' arrays (not a GT point cloud)")
        return npz["xyz"].astype(np.float64), npz["view"].astype(np.int64)


def run(cfg: DictConfig) -> dict:
    """Extracts ``cfg.asset`` into ``cfg.out``; returns stage1.json's content."""
    import torch

    from eval.common.layout import read_scene
    from eval.common.atomic import write_json_atomic
    from gspi.gaussians.ply import read_ply
    from gspi.stage1.config import Stage1Config
    from gspi.stage1.extract import extract_point_cloud
    from gspi.stage1.report import reference_spacing, source_footprint

    t0 = time.perf_counter()
    torch.set_num_threads(int(cfg.threads))
    s1 = Stage1Config.from_dict(OmegaConf.to_container(cfg.stage1, resolve=True))
    asset, out = Path(cfg.asset), Path(cfg.out)
    if not asset.is_file():
        raise MissingInputError(f"{asset}: asset file not found (asset= takes a 2DGS .ply)")
    gaussians = read_ply(asset)
    reference = ref_view = None
    scene_info = None
    if cfg.get("scene"):
        scene_dir = Path(cfg.scene)
        reference, ref_view = read_reference(scene_dir)
        scene = read_scene(scene_dir)
        scene_info = {"dir": str(scene_dir.resolve()), "name": scene.name,
                      "image_size": [scene.height, scene.width]}
        if (scene.height, scene.width) != (s1.image_size, s1.image_size):
            log.warning("scene %s is %dx%d px, Stage I renders %d px: the report is valid, but Table 2's "
                        "measure (gspi.stage2.score_generated) needs stage1.image_size=%d", scene.name,
                        scene.height, scene.width, s1.image_size, scene.height)
    points, renders, stats = extract_point_cloud(gaussians, s1, reference=reference)
    points.save(out / "points.npz")
    summary = {"asset": str(asset.resolve()), "points": str(out / "points.npz"),
               "num_gaussians": int(gaussians.means.shape[0]), "image_size": list(points.image_size),
               "scene": scene_info, **stats}
    if reference is not None:
        footprint = source_footprint(reference, ref_view, renders.K, renders.w2c)
        summary["reference"] = {"count": len(reference), "spacing_floor": reference_spacing(reference, footprint)}
    summary["seconds"]["wall"] = time.perf_counter() - t0
    summary["threads"] = torch.get_num_threads()
    write_json_atomic(out / "stage1.json", summary)
    log.info("%s: %d Gaussians -> %d points (%d unprojected) in %.1f s -> %s", asset.name,
             summary["num_gaussians"], summary["num_points"], stats["filters"][0]["count"],
             summary["seconds"]["wall"], out)
    return summary


main = hydra_cli(run, "gspi_extract", path_keys=("asset", "out", "scene"))  # paths quoted, stated errors as one line


if __name__ == "__main__":
    main()
