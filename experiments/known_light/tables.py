"""The study's tables from its committed scores (results/): Table 2's measure of the known-light
read-outs beside no decomposition and Stage II, with the issue's columns: the three channels'
PSNR, roughness over no decomposition with its paired bootstrap CI over scenes, the metal class
IoU (mean over the ``metal`` scenes) and the multi-material IoU (mean over the ``parts`` scenes
that have metal), and the light identification summaries.

    python -m experiments.known_light.tables           # writes results/*.md
    python -m experiments.known_light.tables --check   # fails if a committed table is stale
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from eval.stats import paired_bootstrap_ci
from experiments.known_light.scene_groups import METAL_SCENES, NO_METAL_SCENES, PARTS_SCENES, iou_mean
from experiments.known_light.end_to_end import table as end_to_end_table
from experiments.known_light.shipping_rule import shipping_rule_table

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
STAGE2_SCORES = HERE.parent / "view_dependence" / "log" / "retraining_shipped" / "exact_whole_xv_nbhd_s0.json"
FULL_SCORES = HERE.parents[1] / "results" / "table2" / "cpu" / "full_s0" / "scores.json"  # the shipped Full, s0
# results/<ablation>_s0_step<N>_exact: run.sh's light-aware Stage II at checkpoint step N (a learning curve)
LEARNED = {
    "light_full": "Stage II `light_full` (the read-out as a condition; 64 training scenes' exact renders; measured "
                  "under the estimated light)",
    "light_residual": "Stage II `light_residual` (`light_full` whose x0 head corrects the read-out; same data and "
                      "measure)",
}
# results/condition_readout: the condition's own read-out columns scored as the prediction (condition.py)
CONDITION = ("the condition's read-out itself (estimated light, cloud normals, 5 000-point subset, 1-NN: what "
             "the learned rows are given)")
# results/<folder>: rows measured behind the held-out scenes' recon=fast assets (run.sh), under fast_true's caption
FAST_ROWS = {
    "condition_readout_fast": "the condition's read-out on the GT cloud in the assets' renders (`light_geometry=cloud`; "
                              "estimated light)",
    "condition_readout_fast_asset": "the condition's read-out as a run reads it (`light_geometry=asset`: Stage I's cloud "
                                    "of the asset, the photos, normals searched at 4 and 8 degrees; estimated light)",
    "condition_readout_fast_asset_profile": "the same, each cell the best of 3 searched normals (`light_normal_profile=3`: "
                                            "what the asset-trained rows below are given)",
    "condition_readout_fast_asset_gated": "the same with the scene-level metal test (`light_metal_min_evidence=1.1`: what "
                                          "the gated asset-trained rows are given)",
    "light_residual_s0_step5000_fast": "Stage II `light_residual` trained on exact renders (step 5000), its condition on "
                                       "the GT cloud in the assets' renders",
    "light_residual_gated_asset_s0_step5000_fast_4samples": "Stage II `light_residual` given the gated condition, seed 0, "
                                                            "step 5000, 4 DDIM samples averaged per point "
                                                            "(`points_measure.num_samples=4`: another measure hash)",
}
READS = {  # results/light_residual_gated_asset_s<seed>_step5000_fast<suffix>: how the prior was read (finding 28)
    "_1step": "read as its posterior mean (one DDIM step: `points_measure.num_steps=1`, another measure hash)",
    "_metalgate": "the metal gate on after training (`readout_metal_gate`, `gate_checkpoint.py`)",
    "_metalgate_1step": "the metal gate on after training, read as its posterior mean (one DDIM step)",
}
FAST_ROWS.update({f"light_residual_gated_asset_s{seed}_step5000_fast{suffix}":
                  f"Stage II `light_residual` given the gated condition, seed {seed}, step 5000, {how}"
                  for suffix, how in READS.items() for seed in (0, 1)})
FAST_ROWS["light_residual_gated_asset_s0_step2737_fast_metalgate_1step"] = (
    "Stage II `light_residual` given the gated condition, seed 0, step 2737 (of 5000), the metal gate on after "
    "training, read as its posterior mean (one DDIM step)")
FAST_ROWS["full_s0_fast_1step"] = "Stage II Full (shipped recipe, s0) read as its posterior mean (one DDIM step)"
METALGATE_READS = {  # results/light_residual_metalgate_asset_s<seed>_step<N>_fast<suffix> (finding 30)
    "_1step": "read as its posterior mean (one DDIM step)",
    "_1step_4samples": "its posterior mean averaged over 4 noise draws (`points_measure.num_samples=4`)",
    "_1step_told_turned90": "read as its posterior mean, told the estimate turned 90 degrees "
                            "(`points_measure.told_light=turned90`: the guard rail)",
    "_1step_told_other": "read as its posterior mean, told another candidate light (`points_measure.told_light=other`)",
}


def curve_rows(prefix: str, behind: str, caption: str, stops: dict[int, int], reads: dict[str, str]) -> dict[str, str]:
    """{results folder: caption} of a two-seed prior measured behind ``behind``'s assets: at the step its
    first call stopped at ({seed: step}; read `_1step` only) and at 5000 (every read):
    results/<prefix>_s<seed>_step<N>_<behind><read>."""
    return {f"{prefix}_s{seed}_step{step}_{behind}{suffix}": f"{caption}, seed {seed}, step {step}, {how}"
            for seed, stop in stops.items() for step in (stop, 5000)
            for suffix, how in reads.items() if step == 5000 or suffix == "_1step"}


FAST_ROWS.update(curve_rows("light_residual_metalgate_asset", "fast", "Stage II `light_residual` given the gated "
                            "condition, trained with the metal gate", {0: 4181, 1: 4233}, METALGATE_READS))
# the same recipe trained and measured behind the early-normal-consistency Stage 0 (finding 12's
# assets of both pools): results/light_residual_metalgate_nc_s<seed>_step<N>_fast_nc<read> (finding 32)
NC_STAGE0 = "Stage 0 `recon=fast recon.loss.normal_from_iter=150 recon.loss.lambda_normal=0.2`"
FAST_ROWS.update(curve_rows("light_residual_metalgate_nc", "fast_nc", f"the same recipe trained and measured behind "
                            f"{NC_STAGE0}", {0: 4207, 1: 4231},
                            {read: METALGATE_READS[read] for read in ("_1step", "_1step_4samples")}))
# the same recipe trained on 64 training scenes drawn with the held-out pool's keys (no matte_finish;
# finding 34): results/light_residual_metalgate_hk_s<seed>_step5000_fast_1step
FAST_ROWS.update({f"light_residual_metalgate_hk_s{seed}_step5000_fast_1step":
                  f"the same recipe trained on the parts pool [0:64] drawn with the held-out keys (no `matte_finish`), "
                  f"seed {seed}, step 5000, {METALGATE_READS['_1step']}" for seed in (0, 1)})
# ... with its x0 head's roughness correction times S after training (finding 35; shrink_checkpoint.py):
# results/light_residual_metalgate_hk_s<seed>_step5000_fast_1step_rough_x<S>
FAST_ROWS.update({f"light_residual_metalgate_hk_s{seed}_step5000_fast_1step_rough_x{scale}":
                  f"the same prior (held-out keys), seed {seed}, its roughness correction times {scale} after "
                  f"training, {METALGATE_READS['_1step']}" for seed in (0, 1) for scale in ("0.25", "0.5", "0.75")})
FAST_ROWS.update({f"light_residual_metalgate_hk_s{seed}_step5000_fast_1step_rough_x0.5_metal_x0":
                  f"the same prior (held-out keys), seed {seed}, its roughness correction times 0.5 and no metallic "
                  f"correction (the read-out's metallic), {METALGATE_READS['_1step']}" for seed in (0, 1)})
FAST_ROWS["full_s0_fast_nc"] = f"Stage II Full (shipped recipe, s0) behind {NC_STAGE0}"
FAST_ROWS["condition_readout_fast_nc_asset_gated"] = f"the gated read-out as a run reads it behind {NC_STAGE0} (what its priors are given)"
CONDITIONS = {  # results/<folder>: its caption
    "exact_true": "exact renders, the capture light known",
    "exact_rotated90": "exact renders, the capture light turned 90 degrees (a wrong light)",
    "exact_other": "exact renders, another pool environment (a wrong light)",
    "fast_true": "Stage 0 `recon=fast` assets' lattice renders, the capture light known (GT normals)",
    "fast_true_surfel": "Stage 0 `recon=fast` assets' lattice renders, the capture light known, the asset's surfel normals",
}


def row(label: str, scores: dict, method: str) -> str:
    mean = scores["mean"][method]
    rough = {k: v["roughness"]["psnr"] for k, v in scores["per_scene"][method].items()}
    base = {k: v["roughness"]["psnr"] for k, v in scores["per_scene"]["no_decomposition"].items()}
    d, lo, hi = paired_bootstrap_ci(rough, base) if method != "no_decomposition" else (0.0, 0.0, 0.0)
    ious = scores["metal_iou"][method]
    return (f"| {label} | {mean['albedo']['psnr']:.2f} | {mean['roughness']['psnr']:.2f} | "
            f"{mean['metallic']['psnr']:.2f} | {mean['avg']['psnr']:.2f} | {d:+.2f} [{lo:+.2f}, {hi:+.2f}] | "
            f"{iou_mean(ious, METAL_SCENES):.2f} | {iou_mean(ious, PARTS_SCENES):.2f} |")


ASSET_TRAINED = {  # results/<prefix>_s<seed>_step<N>_fast: its caption
    "light_residual_asset": "Stage II `light_residual` trained behind the training scenes' assets, read as a run reads it",
    "light_residual_gated_asset": "Stage II `light_residual` trained behind the training scenes' assets, its condition "
                                  "gated by the scene-level metal test (`light_metal_min_evidence=1.1`)",
    "light_residual_metalgate_asset": "the same trained with the metal gate (`readout_metal_gate=true`; finding 28's "
                                      "next recipe)",
}


def asset_trained_runs(prefix: str) -> list[Path]:
    """results/<prefix>_s<seed>_step<N>_fast/scores.json, by seed then step."""
    def key(path: Path) -> tuple[int, int]:
        seed, step = path.parent.name.removeprefix(f"{prefix}_s").removesuffix("_fast").split("_step")
        return int(seed), int(step)
    return sorted(RESULTS.glob(f"{prefix}_s*_step*_fast/scores.json"), key=key)


def asset_trained_rows() -> dict[str, Path]:
    """{caption with seed and step: scores} of every asset-trained run, by prefix, seed, step."""
    rows = {}
    for prefix, caption in ASSET_TRAINED.items():
        for path in asset_trained_runs(prefix):
            seed, step = path.parent.name.removeprefix(f"{prefix}_s").removesuffix("_fast").split("_step")
            rows[f"{caption}, seed {seed}, step {step}"] = path
    return rows


def read_table() -> str:
    head = ("| read-out | albedo | roughness | metallic | avg | roughness - no decomposition [95% CI] | "
            "metal class IoU (7) | multi-material IoU (parts scenes with metal) |\n|---|---|---|---|---|---|---|---|")
    lines = ["# The known-light read-out on the 32 held-out pool scenes (Table 2's measure)", "",
             "Per-view masked PSNR (dB) over the 32 lattice views, averaged over scenes; 20 000 points per "
             "scene, 1-NN fill; GT normals. `map`: each point's best (roughness, metallic) cell; `knn_post`: "
             "the posterior mean of the grid pooled over 16 neighbours (T = 0.1). Generated by "
             "`python -m experiments.known_light.tables` from results/*/scores.json.", ""]
    stage2 = json.loads(STAGE2_SCORES.read_text())
    for folder, caption in CONDITIONS.items():
        runs = {r: RESULTS / folder / r / "scores.json" for r in ("map", "knn_post")}
        if not all(p.is_file() for p in runs.values()):
            continue
        scores = {r: json.loads(p.read_text()) for r, p in runs.items()}
        lines += [f"## {caption}", "", head, row("no decomposition", scores["map"], "no_decomposition")]
        if folder == "exact_true":
            lines.append(row("Stage II `exact_whole_xv_nbhd` (trained and measured on exact renders)", stage2, "stage2"))
            for name, label in LEARNED.items():
                curve = sorted((json.loads(p.read_text()) for p in RESULTS.glob(f"{name}_s0_step*_exact/scores.json")),
                               key=lambda sc: int(sc.get("checkpoint_step") or 0))
                for learned in curve:
                    lines.append(row(f"{label}, step {learned.get('checkpoint_step')}", learned, "stage2"))
            given = RESULTS / "condition_readout" / "scores.json"
            if given.is_file():
                lines.append(row(CONDITION, json.loads(given.read_text()), "stage2"))
        if folder == "fast_true":
            fast = {label: RESULTS / name / "scores.json" for name, label in FAST_ROWS.items()}
            fast.update(asset_trained_rows())
            lines += [row(label, json.loads(p.read_text()), "stage2") for label, p in fast.items() if p.is_file()]
        lines += [row(f"per-point fit, `{r}`", s, "stage2") for r, s in scores.items()] + [""]
    return "\n".join(lines)


def metallic_split_table() -> str:
    """Each fast_true row's metallic PSNR over the scenes without metal and over the others."""
    rows = {"no decomposition": (FULL_SCORES, "no_decomposition"), "Stage II Full (shipped recipe, s0)": (FULL_SCORES, "stage2")}
    rows.update({label: (RESULTS / name / "scores.json", "stage2") for name, label in FAST_ROWS.items()})
    rows.update({label: (p, "stage2") for label, p in asset_trained_rows().items()})
    lines = ["# Where the metallic PSNR comes from, behind the held-out scenes' `recon=fast` assets", "",
             "Table 2's measure (metallic PSNR, dB, per-view, capped at 60 dB): the mean over the 32 held-out "
             f"scenes, over the {len(NO_METAL_SCENES)} whose GT has no metal ({', '.join(NO_METAL_SCENES)}: a "
             "prediction of exactly 0 scores up to the cap there) and over the 26 others. Generated by "
             "`python -m experiments.known_light.tables`.", "",
             "| row | all 32 | no metal (6) | with metal (26) |", "|---|---|---|---|"]
    for label, (path, method) in rows.items():
        if not path.is_file():
            continue
        per = json.loads(path.read_text())["per_scene"][method]
        none = [v["metallic"]["psnr"] for k, v in per.items() if k[:5] in NO_METAL_SCENES]
        some = [v["metallic"]["psnr"] for k, v in per.items() if k[:5] not in NO_METAL_SCENES]
        lines.append(f"| {label} | {np.mean(none + some):.2f} | {np.mean(none):.2f} | {np.mean(some):.2f} |")
    return "\n".join(lines) + "\n"


def identify_table() -> str | None:
    files = sorted(p for p in RESULTS.glob("identify_*.json") if p.name != BUDGET.name)
    if not files:
        return None
    lines = ["# Is the light told by the views?", "",
             "Each held-out scene's light is a member of the candidate set (the pool's 8 capture environments) "
             "turned by a seeded random angle, its radiance scaled by a seeded random gain in [0.5, 2]; "
             "`gspi.light.estimate.estimate_light` on 600 points with GT normals (seconds: the estimate alone, one "
             "thread, 2-5 other jobs on the 2-core VM). `stage1`: through Stage I (its cloud, renders and cloud normals) "
             "on the first 8 scenes, lights unturned, the environment only. Generated from results/identify_*.json.", "",
             "A turn is not wrong where it changes nothing (`overcast` has no azimuthal structure): those scenes "
             "count as right.", "",
             "| views | scenes | environment right | and turn within 15 deg (or irrelevant) | median turn error (deg) | "
             "median abs log2 gain error | median seconds |", "|---|---|---|---|---|---|---|"]
    for path in files:
        s = json.loads(path.read_text())["summary"]
        cell = lambda key, fmt="{}": fmt.format(s[key]) if key in s else "-"  # noqa: E731 (identify_stage1: unturned, env only)
        lines.append(f"| {path.stem.removeprefix('identify_')} | {s['scenes']} | {s['env_identified']} | "
                     f"{cell('env_and_rotation_within_15deg')} | {cell('median_rotation_error_deg', '{:.1f}')} | "
                     f"{cell('median_abs_log2_gain_error', '{:.3f}')} | {cell('median_seconds', '{:.1f}')} |")
    return "\n".join(lines + budget_lines()) + "\n"


BUDGET = RESULTS / "identify_budget.json"  # identify_budget.py: the coarse search on fewer points


def budget_lines() -> list[str]:
    """The coarse search on ``coarse_points`` of the identify points against the default estimate's
    lights on the same points (results/identify_budget.json)."""
    if not BUDGET.is_file():
        return []
    run = json.loads(BUDGET.read_text())
    rows = run["scenes"].values()
    same = sum(r["light"]["env"] == r["reference"]["env"] and r["light"]["rotation_deg"] == r["reference"]["rotation_deg"]
               for r in rows)
    right = sum(r["light"]["env"] == r["capture_env"] for r in rows)
    right_ref = sum(r["reference"]["env"] == r["capture_env"] for r in rows)
    timed = [r for r in rows if "full" in r]
    secs = (f"; on the {len(timed)} scenes timed both ways, median {np.median([r['seconds'] for r in timed]):.1f} s "
            f"against {np.median([r['full']['seconds'] for r in timed]):.1f} s") if timed else ""
    return ["", f"## The coarse search on {run['coarse_points']} of the {run['identify_points']} identify points", "",
            f"`method=light_fit`'s path behind each held-out scene's `recon=fast` asset (Stage I's cloud, the photos; "
            f"`identify_budget.py`), against the default estimate's light on the same points "
            f"({run['reference']}): the same environment and turn in {same} of {len(rows)} scenes; the environment "
            f"right in {right} (default: {right_ref}){secs} (one thread, beside 2-3 jobs)."]


# results/<file> of stage1_read.py: the Stage 0 it read behind (each file's no decomposition is on its own cloud)
FAST, FAST_NORMAL_EARLY = "`recon=fast`", "`recon=fast`, normal consistency from iteration 150 at weight 0.2 (not 360, 0.05)"
STAGE1_READS = {"stage1_read.json": FAST, "stage1_read_normal_search.json": FAST, "stage1_read_normal_profile.json": FAST,
                "stage1_read_normal_early.json": FAST_NORMAL_EARLY, "stage1_read_normal_early_search.json": FAST_NORMAL_EARLY,
                "stage1_read_normal_early_profile.json": FAST_NORMAL_EARLY}
STAGE1_LABELS = {"no_decomposition": "no decomposition (Top-RGB, training constants)",
                 "photos": "read-out in the photos (the asset for geometry)",
                 "renders": "read-out in the asset's renders",
                 "photos_normal_search": "read-out in the photos, each normal searched in a cone (rings 4 and 8 degrees)",
                 "photos_normal_profile": "the same, each grid cell the best of the 3 best-ranked searched normals "
                                          "(`normal_profile=3`)"}


def stage1_rows(path: Path, stage0: str, shown: set) -> list[str]:
    """The table rows of one stage1_read.py file: each read-out not yet ``shown`` for this Stage 0
    ((stage0, read-out) pairs, updated), roughness paired against that file's own no decomposition."""
    scenes = json.loads(path.read_text())["scenes"]
    if len(scenes) < 2:  # a run just begun: nothing to pair yet
        return []
    methods = [m for m in STAGE1_LABELS if all(m in r for r in scenes.values())]
    psnr = {m: {n: {c: r[m]["scores"][c]["psnr"] for c in ("albedo", "roughness", "metallic", "avg")}
                for n, r in scenes.items()} for m in methods}
    count = "" if len(scenes) == 32 else f" ({len(scenes)} scenes)"
    lines = []
    for m in methods:
        if (stage0, m) in shown:  # the same read of the same cloud, in another file
            continue
        shown.add((stage0, m))
        mean = {c: float(np.mean([v[c] for v in psnr[m].values()])) for c in ("albedo", "roughness", "metallic", "avg")}
        rough = {n: v["roughness"] for n, v in psnr[m].items()}
        base = {n: v["roughness"] for n, v in psnr["no_decomposition"].items()}
        d, lo, hi = paired_bootstrap_ci(rough, base) if m != "no_decomposition" else (0.0, 0.0, 0.0)
        ious = {n: r[m]["metal_iou"] for n, r in scenes.items()}
        right = [r[m]["light"]["env"] == r["capture_env"] for r in scenes.values() if "light" in r[m]]
        lines.append(f"| {stage0}{count} | {STAGE1_LABELS[m]} | {mean['albedo']:.2f} | {mean['roughness']:.2f} | "
                     f"{mean['metallic']:.2f} | {mean['avg']:.2f} | {d:+.2f} [{lo:+.2f}, {hi:+.2f}] | "
                     f"{iou_mean(ious, METAL_SCENES):.2f} | {iou_mean(ious, PARTS_SCENES):.2f} | "
                     f"{f'{sum(right)}/{len(right)}' if right else '-'} |")
    return lines


def stage1_table() -> str | None:
    """results/stage1_read*.json (stage1_read.py): the read-out end to end behind Stage 0 and Stage I."""
    files = [(RESULTS / name, stage0) for name, stage0 in STAGE1_READS.items() if (RESULTS / name).is_file()]
    if not files:
        return None
    lines = ["# The read-out behind Stage 0 and Stage I: 32 held-out pool scenes", "",
             "`method=light_fit`'s read-out (the light estimated among the pool's 8 capture environments, 256-neighbour "
             "cloud normals) on Stage I's cloud of each scene's Stage 0 asset, scored on that cloud by Table 2's "
             "measure (`score_generated_points`: per-view masked PSNR over the lattice pixels the cloud covers); metal "
             "IoU over the same pixels; roughness paired against no decomposition on the same cloud. Generated from "
             "results/stage1_read*.json (`stage1_read.py`).", "",
             "| Stage 0 | read-out | albedo | roughness | metallic | avg | roughness - no decomposition [95% CI] | "
             "metal class IoU | multi-material IoU | light right |", "|---|---|---|---|---|---|---|---|---|---|"]
    shown: set = set()
    for path, stage0 in files:
        lines += stage1_rows(path, stage0, shown)
    return "\n".join(lines) + "\n"


def tables() -> dict[Path, str]:
    out = {RESULTS / "known_light.md": read_table(), RESULTS / "metallic_split.md": metallic_split_table(),
           RESULTS / "shipping_rule.md": shipping_rule_table(), RESULTS / "end_to_end.md": end_to_end_table()}
    stage1 = stage1_table()
    if stage1:
        out[RESULTS / "stage1_read.md"] = stage1
    ident = identify_table()
    if ident:
        out[RESULTS / "identify.md"] = ident
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args(argv)
    stale = []
    for path, text in tables().items():
        if args.check:
            if not path.is_file() or path.read_text() != text:
                stale.append(path.name)
        else:
            path.write_text(text)
            print(f"wrote {path.relative_to(HERE.parent.parent)}")
    if stale:
        sys.exit(f"stale: {', '.join(stale)} (run python -m experiments.known_light.tables)")


if __name__ == "__main__":
    main()
