"""The filter report on reconstructed scenes with known geometry (its README.md; the filters: docs/STAGE1.md).

For each scene: render the asset's lattice once, unproject once, then run the filter cascade of
the given config and each filter alone, with distances to the scene's GT point cloud
(``gt_points.npz`` ``xyz``) and that cloud's own spacing (the floor of the measure). Writes
``report.json`` and ``report.md`` into the output folder.

    python -m experiments.stage1_filters.filter_ablation --assets '/tmp/rc/v3_{scene}/point_cloud.ply' \\
        --data /tmp/data_small --out runs/stage1_report \\
        --scenes s002_multipart_ceramic s004_superquadric_metal [--config default] [key=value ...]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from eval.common.atomic import write_json_atomic, write_text_atomic
from eval.common.conf import CONF_DIR
from gspi.stage1.config import Stage1Config
from gspi.stage1.extract import LatticeRenders, apply_filters, render_lattice, unproject_renders
from gspi.point_cloud import PointCloud
from gspi.stage1.report import reference_spacing, source_footprint

FILTERS = ("outliers", "mask_consistency", "depth_consensus")
STAGE1_CONF = Path(CONF_DIR) / "stage1"


def variants(cfg: Stage1Config) -> dict[str, Stage1Config]:
    """"cascade" = the config as given; "<filter> alone" = only that filter, others off."""
    out = {"cascade": cfg}
    for name in FILTERS:
        switched = {f: replace(getattr(cfg, f), enabled=(f == name)) for f in FILTERS}
        out[f"{name} alone"] = replace(cfg, **switched)
    return out


def scene_report(points: PointCloud, renders: LatticeRenders, cfg: Stage1Config,
                 reference: np.ndarray, reference_view: np.ndarray) -> dict:
    """Per variant the per-step report; plus the reference spacing (floor)."""
    footprint = source_footprint(reference.astype(np.float64), reference_view, renders.K, renders.w2c)
    out = {"reference_points": len(reference), "floor": reference_spacing(reference, footprint), "variants": {}}
    for name, variant in variants(cfg).items():
        t0 = time.perf_counter()
        _, steps = apply_filters(points, renders, variant, reference)
        out["variants"][name] = {"steps": steps, "seconds": time.perf_counter() - t0}
    return out


def markdown(reports: dict[str, dict]) -> str:
    """One table: rows = scene x (unprojected, each step of the cascade, each filter alone)."""
    head = ("| scene | step | count | removed | mean (world) | median | p95 | mean (px) | median (px) "
            "| p95 (px) | removed: median (px) |\n" + "|---" * 11 + "|")
    rows = [head]

    def row(scene, label, s):
        rm = s.get("removed_median_px")
        rows.append(f"| {scene} | {label} | {s['count']} | {s.get('removed', '')} | {s['mean_dist']:.4f} | "
                    f"{s['median_dist']:.4f} | {s['p95_dist']:.4f} | {s['mean_px']:.2f} | {s['median_px']:.2f} | "
                    f"{s['p95_px']:.2f} | {'' if rm is None else f'{rm:.2f}'} |")

    for scene, rep in reports.items():
        f = rep["floor"]
        rows.append(f"| {scene} | GT spacing (floor) | {rep['reference_points']} | | {f['mean_dist']:.4f} | "
                    f"{f['median_dist']:.4f} | {f['p95_dist']:.4f} | {f['mean_px']:.2f} | {f['median_px']:.2f} | "
                    f"{f['p95_px']:.2f} | |")
        for i, s in enumerate(rep["variants"]["cascade"]["steps"]):
            row(scene, s["step"] if i == 0 else f"cascade: + {s['step']}", s)
        for name in FILTERS:
            row(scene, name + " alone", rep["variants"][f"{name} alone"]["steps"][-1])
    return "\n".join(rows) + "\n"


def load_config(name: str, overrides: list[str]) -> Stage1Config:
    """conf/stage1/<name>.yaml (with its defaults list) plus dotted ``key=value`` overrides."""
    from omegaconf import OmegaConf

    def compose(n: str):
        node = OmegaConf.load(STAGE1_CONF / f"{n}.yaml")
        bases = [compose(b) for b in node.pop("defaults", []) if b != "_self_"]
        return OmegaConf.merge(*bases, node)

    node = OmegaConf.merge(compose(name), OmegaConf.from_dotlist(overrides))
    return Stage1Config.from_dict(OmegaConf.to_container(node, resolve=True))


def main(argv: list[str] | None = None) -> None:
    from gspi.gaussians.ply import read_ply

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--assets", required=True, help="asset path pattern with {scene}")
    parser.add_argument("--data", required=True, help="dataset folder holding <scene>/gt_points.npz")
    parser.add_argument("--scenes", nargs="+", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--config", default="default", help="conf/stage1/<name>.yaml")
    parser.add_argument("overrides", nargs="*", help="Stage I keys, e.g. outliers.std_ratio=3")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    cfg = load_config(args.config, args.overrides)
    reports = {}
    for scene in args.scenes:
        t0 = time.perf_counter()
        renders = render_lattice(read_ply(args.assets.format(scene=scene)), cfg)
        points = unproject_renders(renders, cfg.alpha_threshold)
        with np.load(Path(args.data) / scene / "gt_points.npz") as gt:
            ref, ref_view = gt["xyz"].astype(np.float64), gt["view"].astype(np.int64)
        reports[scene] = scene_report(points, renders, cfg, ref, ref_view)
        reports[scene]["seconds"] = time.perf_counter() - t0
        print(f"{scene}: {time.perf_counter() - t0:.1f} s", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "report.json", {"config": cfg.to_dict(), "scenes": reports})
    write_text_atomic(out / "report.md", markdown(reports))
    print(markdown(reports))


if __name__ == "__main__":
    main()
