"""How rough a pool's dielectric surfaces are (finding 31's "matte lean", finding 33's control).

    python -m experiments.known_light.pool_roughness LABEL=POOL_DIR [LABEL=POOL_DIR ...] --out FILE.json

For each scene folder (one with ``gt_points.npz``), the ground-truth points with metallic < 0.5:
their mean roughness and the share at r >= 0.7; a pool's figures are the means over its scenes
(each scene weighs the same, as in Table 2's measure), beside the share of metal points, and the
same two over the pool's dielectric points pooled (finding 31's figures).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

MATTE_AT = 0.7   # roughness from which finding 31 calls a dielectric point matte


def scene_roughness(gt_points: Path) -> dict:
    """One scene's dielectric roughness: mean, share >= MATTE_AT; and its share of metal points."""
    with np.load(gt_points) as points:
        roughness, metallic = points["roughness"], points["metallic"]
    dielectric = roughness[metallic < 0.5]
    return {"dielectric_mean_roughness": float(dielectric.mean()) if dielectric.size else None,
            "dielectric_matte_share": float((dielectric >= MATTE_AT).mean()) if dielectric.size else None,
            "metal_share": float((metallic >= 0.5).mean()),
            "dielectric_points": int(dielectric.size),
            "dielectric_roughness_sum": float(dielectric.sum()),
            "dielectric_matte_points": int((dielectric >= MATTE_AT).sum())}


def pool_roughness(pool: Path) -> dict:
    """Means over a pool's scenes of scene_roughness (scenes without dielectric points left out of those)."""
    scenes = sorted(p.parent for p in pool.glob("*/gt_points.npz"))
    if not scenes:
        raise FileNotFoundError(f"{pool}: no scene folder with gt_points.npz")
    rows = [scene_roughness(s / "gt_points.npz") for s in scenes]
    summary = {"scenes": len(rows)}
    for key in ("dielectric_mean_roughness", "dielectric_matte_share", "metal_share"):
        values = [r[key] for r in rows if r[key] is not None]
        summary[key] = round(float(np.mean(values)), 4)
    points = sum(r["dielectric_points"] for r in rows)   # every dielectric point of the pool weighs the same
    summary["pooled_dielectric_mean_roughness"] = round(sum(r["dielectric_roughness_sum"] for r in rows) / points, 4)
    summary["pooled_dielectric_matte_share"] = round(sum(r["dielectric_matte_points"] for r in rows) / points, 4)
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pools", nargs="+", help="LABEL=POOL_DIR")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    result = {}
    for item in args.pools:
        label, _, folder = item.rpartition("=")
        if not folder:
            parser.error(f"{item!r}: expected LABEL=POOL_DIR")
        result[label] = pool_roughness(Path(folder))
        print(label, result[label])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
