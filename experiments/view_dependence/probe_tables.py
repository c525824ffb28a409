"""Issue 52's probe tables, generated from their committed scores (docs/log/probes/, and Table 2
scores of ``evaluate_points``), never typed:

    python -m experiments.view_dependence.probe_tables          # writes docs/results/probes/*.md
    python -m experiments.view_dependence.probe_tables --check  # exit 1 when a committed table differs

* ``stage0_view_dependence.md`` from ``docs/log/probes/stage0_view_dependence.json``;
* ``patch_inference.md``: ``docs/log/probes/patch_inference/<mode>.json`` (``whole``, ``patch512``),
  per scene and the paired differences (95 % bootstrap CI over scenes);
* ``cue_oracle.md`` from ``docs/log/probes/cue_oracle.json``;
* ``retraining.md``: the Table 2 scores of ``gspi-reproduce table=2 scale=probe recon=<name>``
  (``docs/results/scores/table2_probe_<name>/``) or of its checkpoints measured before the last
  step (``docs/log/probes/retraining/<name>.json``), one row per Stage 0 config.
A table whose scores are not committed yet is left out.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from eval.stats import paired_bootstrap_ci

ROOT = Path(__file__).resolve().parents[2]
PROBES = ROOT / "docs" / "log" / "probes"
OUT = ROOT / "docs" / "results" / "probes"
CHANNELS = ("albedo", "roughness", "metallic")


def scene_avg(per_scene: dict) -> dict[str, float]:
    return {s: float(np.mean([v[c]["psnr"] for c in CHANNELS])) for s, v in per_scene.items()}


def channel(per_scene: dict, name: str) -> dict[str, float]:
    return {s: float(v[name]["psnr"]) for s, v in per_scene.items()}


def is_multi_part(scene: str) -> bool:
    return "multipart" in scene


def fmt_ci(mean: float, lo: float, hi: float) -> str:
    return f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def patch_table(whole: dict, patch: dict) -> str:
    """Per scene and in the mean: avg, roughness, metallic PSNR and metal IoU, whole vs patches."""
    common = sorted(set(whole["per_scene"]["stage2"]) & set(patch["per_scene"]["stage2"]))  # patches ran on a subset
    pick = lambda d: {k: v for k, v in d.items() if k in common}  # noqa: E731
    w, p = pick(whole["per_scene"]["stage2"]), pick(patch["per_scene"]["stage2"])
    wi, pi = pick(whole["metal_iou"]["stage2"]), pick(patch["metal_iou"]["stage2"])
    nd = pick(whole["per_scene"]["no_decomposition"])
    lines = ["| scene | avg whole | avg patches | roughness whole | roughness patches | metallic whole | "
             "metallic patches | metal IoU whole | metal IoU patches |", "|---" * 9 + "|"]
    iou = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
    for s in sorted(w):
        lines.append(f"| {s} | {scene_avg(w)[s]:.2f} | {scene_avg(p)[s]:.2f} | {w[s]['roughness']['psnr']:.2f} | "
                     f"{p[s]['roughness']['psnr']:.2f} | {w[s]['metallic']['psnr']:.2f} | {p[s]['metallic']['psnr']:.2f} | "
                     f"{iou(wi.get(s))} | {iou(pi.get(s))} |")
    out = [f"| measure ({len(common)} held-out scenes) | whole cloud | 512-point patches | patches - whole [95% CI] |",
           "|---|---|---|---|"]
    for label, get in (("avg", scene_avg), ("roughness", lambda d: channel(d, "roughness")),
                       ("metallic", lambda d: channel(d, "metallic"))):
        a, b = get(w), get(p)
        out.append(f"| {label} PSNR | {np.mean(list(a.values())):.2f} | {np.mean(list(b.values())):.2f} | "
                   f"{fmt_ci(*paired_bootstrap_ci(b, a))} |")
    out.append(f"| roughness PSNR, no decomposition | {np.mean(list(channel(nd, 'roughness').values())):.2f} | | |")
    for label, keep in (("metal IoU, scenes with metal", lambda s: True),
                        ("metal IoU, multi-part scenes", is_multi_part)):
        a = {s: v for s, v in wi.items() if v is not None and keep(s)}
        b = {s: v for s, v in pi.items() if v is not None and keep(s)}
        both = sorted(set(a) & set(b))
        if both:
            out.append(f"| {label} ({len(both)}) | {np.mean([a[s] for s in both]):.2f} | "
                       f"{np.mean([b[s] for s in both]):.2f} | {fmt_ci(*paired_bootstrap_ci(b, a))} |")
    head = (f"The shipped checkpoint ({whole.get('checkpoint', '?')}) on {len(common)} held-out pool scenes "
            f"({whole['data']}: the metal class and the multi-part scenes), {whole['num_steps']} DDIM steps, "
            f"{whole.get('max_points')} points per scene.")
    return head + "\n\n" + "\n".join(out) + "\n\nPer scene:\n\n" + "\n".join(lines) + "\n"


def retraining_table(by_recon: dict[str, list[dict]]) -> str:
    """One row per Stage 0 config: its Full model's held-out channels, metal class and multi-part."""
    lines = ["| Stage 0 of the conditions | training step | seeds | albedo | roughness | metallic | avg | roughness - no decomposition [95% CI] | metal IoU (scenes with metal) | metal IoU (multi-part) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for recon, runs in by_recon.items():
        if not runs:
            continue
        ch = {c: np.mean([np.mean(list(channel(r["per_scene"]["stage2"], c).values())) for r in runs]) for c in CHANNELS}
        rough = {(s, i): v for i, r in enumerate(runs) for s, v in channel(r["per_scene"]["stage2"], "roughness").items()}
        base = {(s, i): v for i, r in enumerate(runs)
                for s, v in channel(r["per_scene"]["no_decomposition"], "roughness").items()}
        ious = [v for r in runs for v in r["metal_iou"]["stage2"].values() if v is not None]
        multi = [v for r in runs for s, v in r["metal_iou"]["stage2"].items() if v is not None and is_multi_part(s)]
        steps = ", ".join(str(r.get("checkpoint_step", "?")) for r in runs)
        lines.append(f"| {recon} | {steps} | {len(runs)} | {ch['albedo']:.2f} | {ch['roughness']:.2f} | {ch['metallic']:.2f} | "
                     f"{np.mean(list(ch.values())):.2f} | {fmt_ci(*paired_bootstrap_ci(rough, base))} | "
                     f"{np.mean(ious):.2f} | {np.mean(multi):.2f} |")
    if len(by_recon.get("fast", [])) == 1 and all(len(by_recon.get(r, [])) == 1 for r in by_recon):
        ref = by_recon["fast"][0]["per_scene"]["stage2"]
        for recon, runs in by_recon.items():
            if recon != "fast":
                other = runs[0]["per_scene"]["stage2"]
                lines.append("")
                lines.append(f"{recon} - fast, paired over the held-out scenes: avg {fmt_ci(*paired_bootstrap_ci(scene_avg(other), scene_avg(ref)))}, "
                             f"roughness {fmt_ci(*paired_bootstrap_ci(channel(other, 'roughness'), channel(ref, 'roughness')))}, "
                             f"metallic {fmt_ci(*paired_bootstrap_ci(channel(other, 'metallic'), channel(ref, 'metallic')))} dB.")
    return "\n".join(lines) + "\n"


def tables() -> dict[str, str]:
    """{file name: markdown} of every probe whose scores are committed."""
    from experiments.view_dependence.stage0_probe import class_table

    out = {}
    stage0 = PROBES / "stage0_view_dependence.json"
    if stage0.is_file():
        out["stage0_view_dependence.md"] = class_table(json.loads(stage0.read_text()))
    whole, patch = PROBES / "patch_inference" / "whole.json", PROBES / "patch_inference" / "patch512.json"
    if whole.is_file() and patch.is_file():
        out["patch_inference.md"] = patch_table(json.loads(whole.read_text()), json.loads(patch.read_text()))
    oracle = PROBES / "cue_oracle.json"
    if oracle.is_file():
        data = json.loads(oracle.read_text())
        rows = ["| conditions | features | metal IoU | metal IoU (multi-part) | roughness PSNR | constant |",
                "|---|---|---|---|---|---|"]
        for version, sets in data["versions"].items():
            for fs, r in sets.items():
                rows.append(f"| {version} | {fs} | {r['metal_iou']:.2f} | {r['metal_iou_multi_part']:.2f} | "
                            f"{r['roughness_psnr']:.2f} | {r['roughness_psnr_constant']:.2f} |")
        out["cue_oracle.md"] = "\n".join(rows) + "\n"
    by_recon: dict[str, list[dict]] = {}
    for p in sorted((ROOT / "docs" / "results" / "scores").glob("table2_probe_*/full_s*/scores.json")):
        by_recon.setdefault(p.parent.parent.name.removeprefix("table2_probe_"), []).append(json.loads(p.read_text()))
    for p in sorted((PROBES / "retraining").glob("*.json")):  # runs measured before their last step (cut for time)
        by_recon.setdefault(p.stem, []).append(json.loads(p.read_text()))
    if by_recon:
        out["retraining.md"] = ("Full of the probe recipe (32 matte-pool scenes, cpu_pool224_pixel), trained under each "
                                "Stage 0's conditions and measured on the 32 held-out scenes reconstructed by the same "
                                "Stage 0 (10 DDIM steps, 20000 points).\n\n" + retraining_table(by_recon))
    return {name: f"<!-- generated by python -m experiments.view_dependence.probe_tables; do not edit -->\n{text}"
            for name, text in out.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args(argv)
    stale = []
    for name, text in tables().items():
        path = OUT / name
        if args.check:
            if not path.is_file() or path.read_text() != text:
                stale.append(str(path))
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
    if stale:
        print("stale (run python -m experiments.view_dependence.probe_tables): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
