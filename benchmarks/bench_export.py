"""The glTF export of GS-PI's assets, measured: time, size, round trip, scores against GT.

    PYTHONPATH=. python benchmarks/bench_export.py demo_out/runs/method=gspi/work demo_out/data /tmp/glb_bench
    PYTHONPATH=. python benchmarks/bench_export.py WORK DATA OUT --set texture.source=surfels mesh.resolution=96
    PYTHONPATH=. python benchmarks/bench_export.py WORK DATA OUT --command-only [--cold]

For each ``WORK/<scene>/pbr_gs.ply``:
* the command a user waits for, ``gspi-export asset=<ply> out=<glb>`` (docs/EXPORT.md), run as a
  subprocess: its wall seconds, Python start-up and imports included (``--command-only``: this
  and nothing else). The rasterizer's numba kernels are compiled on a fresh install's first
  call (~30 s on the 2-core VM) and cached on disk; ``--cold`` points ``NUMBA_CACHE_DIR`` at an
  empty folder so the command pays that compilation, else the cache is used as a user's second
  call would;
* export it (``gspi.export.asset.export_asset``; ``--set`` overrides conf/gspi_export_asset.yaml's
  ``export`` keys): seconds per step and GLB bytes;
* the round trip of docs/EXPORT.md: ``python -m gspi.cli.data import.glb=<glb> out=<dir>
  preset=small`` (gspi-data), then ``gspi.export.roundtrip.compare_imported`` on its test views:
  PSNR of the re-imported maps against the PBR-GS renders at the same cameras;
* against ground truth: the GLB ray-cast (``gspi.data.assets.mesh_render``, as the importer does) and
  the PBR-GS asset rasterized (Stage III's renderer) at the GT scene ``DATA/<scene>``'s test
  cameras, each scored by ``eval.metrics.masked_psnr`` in the GT mask (no albedo alignment, so
  the two numbers differ only by the export), over the whole GT mask and over the GT pixels the
  GLB covers (``*_hit``: the material loss without the silhouette's).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from benchmarks.common import REPO, command_seconds, machine
from eval.common.layout import MATERIAL_CHANNELS, read_scene, read_view_file
from eval.metrics import masked_psnr


def export_config(overrides: list[str]):
    from gspi.export.config import ExportConfig

    base = OmegaConf.load(REPO / "conf" / "gspi_export_asset.yaml").export
    cfg = OmegaConf.merge(base, OmegaConf.from_dotlist(overrides))
    return ExportConfig.from_dict(OmegaConf.to_container(cfg, resolve=True))


def glb_maps_at(glb: Path, views) -> list[dict]:
    """The GLB's maps at GT cameras, as gspi-data's importer renders them (unit frame, 2x2 rays)."""
    from eval.relight import prefilter_environment
    from gspi.data.assets.gltf import read_gltf
    from gspi.data.assets.mesh_render import render_mesh_views, unit_frame_mesh

    mesh = unit_frame_mesh(read_gltf(glb))
    cameras = []
    for v in views:
        centre = (v.camera_center - mesh.center) * mesh.scale
        w2c = v.w2c.copy()
        w2c[:3, 3] = -w2c[:3, :3] @ centre
        cameras.append((v.K, w2c, 0))
    width, height = int(views[0].K[0, 2] * 2), int(views[0].K[1, 2] * 2)
    env = prefilter_environment(torch.ones(16, 32, 3))
    hw = (height, width, -1)
    return [{"albedo": r.albedo_srgb.reshape(hw), "roughness": r.roughness.reshape(hw), "metallic": r.metallic.reshape(hw),
             "mask": r.mask.reshape(height, width)}
            for r in render_mesh_views(mesh, cameras, height, width, env=env, supersample=2)]


def gt_scores(asset, glb: Path, gt_dir: Path) -> dict:
    from gspi.stage3.export import render_material_maps

    scene = read_scene(gt_dir)
    views = scene.split_views("test")
    glb_maps = glb_maps_at(glb, views)
    gs = render_material_maps(asset, np.stack([v.K for v in views]), np.stack([v.w2c for v in views]),
                              scene.width, scene.height)
    kinds = ("glb", "pbr_gs", "glb_hit", "pbr_gs_hit")  # *_hit: only GT pixels the GLB covers
    out = {k: {c: [] for c in MATERIAL_CHANNELS} for k in kinds}
    missed = []
    for i, view in enumerate(views):
        vdir = scene.view_dir("test", view.id)
        mask = torch.from_numpy(read_view_file(vdir, "mask.png")[..., 0] > 0.5)
        hit = mask & torch.from_numpy(np.asarray(glb_maps[i]["mask"]))
        missed.append(float(1 - hit.sum() / mask.sum()))
        for c in MATERIAL_CHANNELS:
            gt = torch.from_numpy(read_view_file(vdir, f"{c}.png"))
            pred = {"glb": torch.from_numpy(np.asarray(glb_maps[i][c], np.float32)), "pbr_gs": torch.from_numpy(gs[c][i])}
            for k in ("glb", "pbr_gs"):
                out[k][c].append(masked_psnr(pred[k], gt, mask))
                out[f"{k}_hit"][c].append(masked_psnr(pred[k], gt, hit))
    scores = {k: {c: float(np.mean(v)) for c, v in d.items()} for k, d in out.items()}
    return {**scores, "gt_pixels_missed": float(np.mean(missed))}


def export_command(ply: Path, glb: Path, *, cold: bool) -> float:
    """Wall seconds of ``gspi-export asset=<ply> out=<glb>`` (module docstring); ``cold``: an empty
    numba cache (the first call on a fresh machine)."""
    import tempfile

    with tempfile.TemporaryDirectory() as numba_cache:
        return command_seconds("gspi-export", [f"asset='{ply}'", f"out='{glb}'"],
                               env={"NUMBA_CACHE_DIR": numba_cache} if cold else None)


def main() -> None:
    from gspi.export.asset import export_asset
    from gspi.export.roundtrip import compare_imported
    from gspi.gaussians.ply import read_ply

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path, help="gspi-run's work/ folder (<scene>/pbr_gs.ply)")
    ap.add_argument("data", type=Path, help="the GT dataset (<scene>/scene.json)")
    ap.add_argument("out", type=Path)
    ap.add_argument("--set", nargs="*", default=[], help="export.* overrides, e.g. texture.size=1024")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--command-only", action="store_true", help="time the gspi-export command only")
    ap.add_argument("--cold", action="store_true", help="the command with an empty numba cache (first call)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cfg = export_config(args.set)
    print(machine())
    print("export config:", json.dumps(cfg.to_dict()))
    rows = []
    for ply in sorted(args.work.glob("*/pbr_gs.ply")):
        name = ply.parent.name
        out = args.out / name
        out.mkdir(parents=True, exist_ok=True)
        command_s = export_command(ply, out / "command.glb", cold=args.cold)
        print(f"{name}: gspi-export asset=... out=... {command_s:.1f} s wall "
              f"({'empty' if args.cold else 'warm'} numba cache, default config)", flush=True)
        if args.command_only:
            continue
        record = export_asset(ply, out / "asset.glb", cfg)
        imported = out / "imported"
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        subprocess.run([sys.executable, "-m", "gspi.cli.data", f"import.glb={out / 'asset.glb'}", f"out={imported}",
                        "preset=small"], check=True, env=env, capture_output=True)
        asset = read_ply(ply)
        trip = compare_imported(asset, imported / "asset")
        scores = gt_scores(asset, out / "asset.glb", args.data / name)
        row = {"scene": name, "seconds": record["seconds"], "bytes": record["bytes"], "faces": record["mesh"]["faces"],
               "roundtrip_psnr": trip["psnr"], "mask_iou": trip["mask_iou"], "gt_psnr": scores}
        (out / "bench.json").write_text(json.dumps({**row, "export": record}, indent=1))
        rows.append(row)
        print(f"{name}: export {record['seconds']['total_s']:.1f} s, {record['bytes'] / 1e6:.2f} MB, "
              f"{row['faces']} faces; round trip PSNR "
              + " ".join(f"{c} {trip['psnr'][c]:.2f}" for c in MATERIAL_CHANNELS)
              + f" dB, mask IoU {trip['mask_iou']:.3f}; vs GT (GLB / PBR-GS) "
              + " ".join(f"{c} {scores['glb'][c]:.2f}/{scores['pbr_gs'][c]:.2f}" for c in MATERIAL_CHANNELS)
              + f"; GT pixels the GLB misses {100 * scores['gt_pixels_missed']:.1f} %, where it covers (GLB / PBR-GS) "
              + " ".join(f"{c} {scores['glb_hit'][c]:.2f}/{scores['pbr_gs_hit'][c]:.2f}" for c in MATERIAL_CHANNELS))
    if not rows:
        return
    mean = lambda f: float(np.mean([f(r) for r in rows]))  # noqa: E731
    print("mean: export {:.1f} s, {:.2f} MB; round trip ".format(mean(lambda r: r["seconds"]["total_s"]),
                                                               mean(lambda r: r["bytes"]) / 1e6)
          + " ".join(f"{c} {mean(lambda r: r['roundtrip_psnr'][c]):.2f}" for c in MATERIAL_CHANNELS)
          + " dB; GLB - PBR-GS vs GT "
          + " ".join(f"{c} {mean(lambda r: r['gt_psnr']['glb'][c] - r['gt_psnr']['pbr_gs'][c]):+.2f}"
                     for c in MATERIAL_CHANNELS) + " dB (where the GLB covers: "
          + " ".join(f"{c} {mean(lambda r: r['gt_psnr']['glb_hit'][c] - r['gt_psnr']['pbr_gs_hit'][c]):+.2f}"
                     for c in MATERIAL_CHANNELS) + " dB)")


if __name__ == "__main__":
    main()
