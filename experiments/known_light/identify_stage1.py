"""Is the light told through Stage I? For held-out scenes of a reconstructed pool (``recon=fast``
assets), Stage I on the asset (its cloud and lattice renders, as gspi-run's pipeline), the cloud's
own normals (``cloud_normals_of``), then ``estimate_light`` among the pool's 8 capture environments
(unturned, gain 1): the method's path, next to ``identify.py``'s GT-normals path on the same renders.

    python -m experiments.known_light.identify_stage1 HELDOUT_TEST RHELDOUT --scenes 8 --out results/identify_stage1.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from eval.common.imageio import read_exr
from eval.common.layout import read_scene, read_splits
from eval.relight import prefilter_environment
from experiments.known_light.fit import POOL_ENVS
from experiments.known_light.scene_fit import env_path
from gspi.gaussians.ply import read_ply
from gspi.light.estimate import estimate_light
from gspi.stage1.config import Stage1Config
from gspi.stage1.extract import extract_point_cloud
from gspi.stage2.lattice_cameras import LatticeCameras
from gspi.stage2.light_condition import cloud_normals_of, readout_subset
from gspi.stage2.light_views import observe_points

ROOT = Path(__file__).resolve().parents[2]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("recon", type=Path)
    ap.add_argument("--scenes", type=int, default=8)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    names = read_splits(args.data)["test"][: args.scenes]
    cands = {e: prefilter_environment(torch.from_numpy(read_exr(env_path(args.data / names[0], e)).astype(np.float32)))
             for e in POOL_ENVS}
    cfg = Stage1Config.from_dict(yaml.safe_load((ROOT / "conf" / "stage1" / "default.yaml").read_text()))
    rows = []
    for name in names:
        t0 = time.perf_counter()
        points, renders, _ = extract_point_cloud(read_ply(args.recon / name / "asset" / "point_cloud.ply"), cfg)
        cams = LatticeCameras.from_renders(renders)
        xyz = points.xyz.astype(np.float64)
        sub = readout_subset(len(xyz))
        obs = observe_points(renders.rgb, renders.depth, cams, xyz[sub], cloud_normals_of(xyz, points.view, cams)(sub))
        est = estimate_light(obs, cands)
        truth = read_scene(args.data / name).capture_env
        rows.append({"scene": name, "env": truth, "estimate": est.env, "rotation_deg": est.rotation_deg,
                     "gain": est.gain, "margin": est.margin, "seconds": round(time.perf_counter() - t0, 1)})
        print(f"{name}: {truth} -> {est.env} {est.rotation_deg:.1f} deg x{est.gain:.2f} (margin {est.margin:.2f})",
              flush=True)
    summary = {"scenes": len(rows), "env_identified": sum(r["env"] == r["estimate"] for r in rows)}
    print(json.dumps(summary))
    args.out.write_text(json.dumps({"summary": summary, "views": "Stage I renders of recon=fast assets",
                                    "normals": "cloud (Stage I)", "scenes": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
