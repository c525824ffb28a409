"""What a speed budget costs: GS-PI's material time and its scores under several Stage II / Stage III
budgets, paired over scenes against a reference budget, beside joint IR's material time.

Each budget is one ``gspi-run`` of the scenes (one process, one thread; the first scene carries the
process's imports, for every method alike); joint IR runs once. Per scene: the material time Table 1
counts (``predictions/<scene>/meta.json``) and each channel's PSNR (the mean over the scene's views in
``eval/per_view.csv``, relight over views x environments). Per budget: total material time, its ratio
to joint IR's, and each channel's mean paired difference to the reference with its 95 % bootstrap
interval (``eval.stats.paired_bootstrap_ci``, the tables' own).

    python -m benchmarks.budget_quality --data demo_out/data --assets checkpoints/demo_assets \\
        --out docs/log/speed/asset_budget_demo.json
    python -m benchmarks.budget_quality --data HELDOUT --recon tiny --out docs/log/speed/asset_budget_tiny.json

``--budget NAME OVERRIDE ...`` (repeatable) replaces the default budgets below; the first is the reference.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import pandas as pd

from benchmarks.bench_pipeline import GSPI_STAGES, material_cpu
from benchmarks.common import REPO, command_seconds, machine
from eval.stats import paired_bootstrap_ci

CHANNELS = ("albedo", "roughness", "metallic", "relight")
# the demo's budget before issue 68's asset-sized one (conf/experiment/demo.yaml), then the candidates
BUDGETS = {
    "steps10_it100": ["stage2.inference.num_steps=10", "stage3.iterations=100"],
    "steps10_it100_ppg2": ["stage2.inference.num_steps=10", "stage3.iterations=100",
                           "stage2.inference.points_per_gaussian=2"],
    "steps10_it64": ["stage2.inference.num_steps=10", "stage3.iterations=64"],
    "steps10_it64_ppg2": ["stage2.inference.num_steps=10", "stage3.iterations=64",
                          "stage2.inference.points_per_gaussian=2"],
    "steps10_it64_ppg1": ["stage2.inference.num_steps=10", "stage3.iterations=64",
                          "stage2.inference.points_per_gaussian=1"],
    "steps10_it100_ppg2_plateau": ["stage2.inference.num_steps=10", "stage3.iterations=100",
                                   "stage2.inference.points_per_gaussian=2", "stage3.plateau_tol=0.02"],
}


def portable(path: Path) -> str:
    """``path`` as the record names it: relative to the repository when inside it, else its name in
    capitals (a committed record names no machine path; say in the docs how the data were made)."""
    try:
        return str(path.resolve().relative_to(REPO))
    except ValueError:
        return path.name.upper()


def scene_psnr(run: Path) -> dict[str, dict[str, float]]:
    """{scene: {channel: mean PSNR over its views (relight: views x environments)}} of a scored run."""
    rows = pd.read_csv(run / "eval" / "per_view.csv")
    means = rows.groupby(["scene", "channel"])["psnr"].mean()
    return {scene: {ch: float(means[scene, ch]) for ch in CHANNELS if (scene, ch) in means.index}
            for scene in sorted(rows["scene"].unique())}


def material_seconds(run: Path, scenes: list[str]) -> dict[str, float]:
    return {s: json.loads((run / "predictions" / s / "meta.json").read_text())["runtime_s"]["material"]
            for s in scenes}


def material_cpu_seconds(run: Path, scenes: list[str]) -> dict[str, float]:
    """Each scene's CPU seconds over its material stages (GS-PI's, or a baseline's one ``material``
    stage; bench_pipeline.material_cpu: robust to other jobs)."""
    stages = (*GSPI_STAGES, "material")
    return {s: round(material_cpu(json.loads((run / "predictions" / s / "meta.json").read_text()), stages), 3)
            for s in scenes}


def run_method(data: Path, out: Path, method: str, source: list[str], overrides: list[str]) -> dict:
    seconds = command_seconds("gspi-run", [f"data={data}", f"out={out}", f"method={method}", "threads=1",
                                           "logger=none", "progress=false", "figures=false", *source, *overrides],
                              cwd=REPO)
    scenes = json.loads((out / "result.json").read_text())["scenes"]
    return {"wall_s": round(seconds, 1), "material_s": material_seconds(out, scenes),
            "material_cpu_s": material_cpu_seconds(out, scenes), "psnr": scene_psnr(out)}


def compare(budget: dict, reference: dict) -> dict[str, list[float]]:
    """{channel: [mean, lo, hi]} of the paired difference budget - reference over scenes."""
    out = {}
    for ch in CHANNELS:
        v = {s: p[ch] for s, p in budget["psnr"].items() if ch in p}
        r = {s: p[ch] for s, p in reference["psnr"].items() if ch in p}
        if len(v.keys() & r.keys()) >= 2:
            out[ch] = [round(x, 3) for x in paired_bootstrap_ci(v, r)]
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a scored dataset (splits.json + scenes)")
    ap.add_argument("--assets", default=None, help="2DGS assets (gspi-run assets=); else --recon reconstructs them")
    ap.add_argument("--recon", default="fast", help="Stage 0 preset when the assets are reconstructed (cached)")
    ap.add_argument("--budget", nargs="+", action="append", metavar=("NAME", "OVERRIDE"), default=None)
    ap.add_argument("--out", type=Path, required=True, help="the JSON written")
    args = ap.parse_args(argv)
    budgets = {b[0]: b[1:] for b in args.budget} if args.budget else BUDGETS
    source = [f"recon={args.recon}"] + ([f"assets={args.assets}"] if args.assets else [])
    load = os.getloadavg()[0]
    runs = {}
    with tempfile.TemporaryDirectory(prefix="budget_quality_") as tmp:
        tmp = Path(tmp)
        # joint IR first: a reconstructed asset is then cached for every GS-PI budget alike
        joint = run_method(args.data.resolve(), tmp / "joint_ir", "joint_ir", source, [])
        for name, overrides in budgets.items():
            print(f"{name}: {' '.join(overrides)}", flush=True)
            runs[name] = run_method(args.data.resolve(), tmp / name, "gspi", source, overrides)
    joint_total = sum(joint["material_s"].values())
    joint_cpu = sum(joint["material_cpu_s"].values())
    reference = next(iter(runs))
    summary = {}
    for name, run in runs.items():
        total = sum(run["material_s"].values())
        cpu = sum(run["material_cpu_s"].values())
        summary[name] = {"material_s": round(total, 1), "ratio_to_joint_ir": round(total / joint_total, 3),
                         "material_cpu_s": round(cpu, 1), "cpu_ratio_to_joint_ir": round(cpu / joint_cpu, 3),
                         "minus_reference": compare(run, runs[reference]) if name != reference else {}}
        print(f"{name:30s} material {total:6.1f} s  / joint IR {total / joint_total:.2f} (CPU {cpu / joint_cpu:.2f})  "
              + "  ".join(f"{ch} {d[0]:+.2f} [{d[1]:+.2f}, {d[2]:+.2f}]"
                          for ch, d in summary[name]["minus_reference"].items()), flush=True)
    data = portable(args.data)
    record = {"what": __doc__.splitlines()[0], "machine": machine(), "load_average_at_start": round(load, 2),
              "data": data, "source": source, "reference": reference,
              "budgets": budgets, "summary": summary, "joint_ir": joint, "runs": runs,
              "command": "python -m benchmarks.budget_quality " + " ".join(
                  f"--{k} {v}" for k, v in (("data", data), ("assets", args.assets), ("recon", args.recon)) if v)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"joint IR material {joint_total:.1f} s; wrote {args.out}")


if __name__ == "__main__":
    main()
