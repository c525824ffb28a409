"""Which of Stage II's inputs loses the material end to end: swap one condition at a time from
the scene's ground-truth renders to a 2DGS asset's renders, on the scene's GT point cloud.

Stage II is trained with conditions built from a scene's GT lattice renders (``rgb.exr``); in
a run they come from the 2DGS asset's lattice renders (Stage I). With the same points (the GT
cloud) and the same model, Table 2's measure is taken three times:

- ``gt``: every condition from the GT renders (Table 2's measure as is);
- ``asset_top_rgb``: the per-point colour (Top-RGB) read from the asset's render of the point's
  source view at its stored pixel, the global prior from the GT renders;
- ``asset_prior``: Top-RGB from the GT renders, the global prior computed from the asset's
  lattice renders (the lattice ``rgb.exr`` files replaced by them).

A drop from ``gt`` to one of the others names the input the asset degrades (docs/log/diary.md
"The ladder-fixed checkpoint end to end": on the metal demo scene the prior, not Top-RGB).

    python -m experiments.condition_swap.condition_swap CKPT SCENE_DIR ASSET_PLY OUT [--baseline-train POOL]
        [--num-steps 10] [--max-points 20000]

Each variant is a dataset view under ``OUT/<variant>/`` (symlinks to the scene's files, the
swapped file written), scored into ``OUT/<variant>/eval``; ``OUT/condition_swap.json`` holds
the per-channel PSNRs.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import numpy as np
import torch

from gspi.data.pool.asset_conditions import write_asset_conditions

VARIANTS = ("gt", "asset_top_rgb", "asset_prior")
VARIANT_CONDITIONS = {"gt": (), "asset_top_rgb": ("top_rgb",), "asset_prior": ("prior",)}


def asset_lattice_rgb(asset_ply: Path, image_size: tuple[int, int]) -> np.ndarray:
    """[V, H, W, 3] linear radiance of the asset's canonical lattice renders."""
    from gspi.gaussians.lattice_render import render_lattice
    from gspi.gaussians.ply import read_asset_ply

    gaussians, _ = read_asset_ply(asset_ply)
    return render_lattice(gaussians, image_size=image_size).rgb


def write_variant(variant: str, scene_dir: Path, asset_rgb: np.ndarray, out: Path) -> Path:
    """The dataset view of one variant (a one-scene test split); returns its root."""
    root = out / variant
    write_asset_conditions(Path(scene_dir), asset_rgb, root / Path(scene_dir).name, VARIANT_CONDITIONS[variant])
    (root / "splits.json").write_text(json.dumps({"train": [], "val": [], "test": [Path(scene_dir).name]}))
    return root


def condition_swap(checkpoint: Path, scene_dir: Path, asset_ply: Path, out: Path, *, num_steps: int = 10,
                   max_points: int | None = 20000, baseline_train: str | None = None) -> dict:
    """{variant: {channel: PSNR}} on the scene's GT cloud (module docstring)."""
    from eval.common.layout import read_scene
    from gspi.stage2.checkpoint import load_stage2_checkpoint
    from gspi.stage2.evaluate_points import checkpoint_source, evaluate_checkpoint

    scene = read_scene(scene_dir)
    asset_rgb = asset_lattice_rgb(asset_ply, (scene.height, scene.width))
    model, cfg = load_stage2_checkpoint(checkpoint)
    result = {}
    for variant in VARIANTS:
        root = write_variant(variant, Path(scene_dir), asset_rgb, Path(out))
        evaluate_checkpoint(model, cfg, root, root / "eval", split="test", num_steps=num_steps, seed=0,
                            source=checkpoint_source(checkpoint), max_points=max_points,
                            baseline_train=baseline_train)
        scores = json.loads((root / "eval" / "scores.json").read_text())["per_scene"]["stage2"][scene_dir.name]
        result[variant] = {c: round(float(v["psnr"]), 2) for c, v in scores.items()}
    (Path(out) / "condition_swap.json").write_text(json.dumps(
        {"checkpoint": str(checkpoint), "scene": str(scene_dir), "asset": str(asset_ply), "psnr": result}, indent=1))
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("scene", type=Path)
    parser.add_argument("asset", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--num-steps", type=int, default=10)
    parser.add_argument("--max-points", type=int, default=20000)
    parser.add_argument("--baseline-train", required=True,
                        help="dataset whose train split gives the no-decomposition constants (e.g. the pool)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(args.threads)
    result = condition_swap(args.checkpoint, args.scene, args.asset, args.out, num_steps=args.num_steps,
                            max_points=args.max_points, baseline_train=args.baseline_train)
    for variant, psnr in result.items():
        print(variant, "  ".join(f"{c} {v:.2f}" for c, v in psnr.items()))


if __name__ == "__main__":
    main()
