"""Issue 52's probe tables, generated from their committed scores (log/, and Table 2 scores of
``evaluate_points``), never typed. Paths are under this study's folder (experiments/view_dependence/)
unless they start with docs/ or benchmarks/ (the product's committed scores):

    python -m experiments.view_dependence.probe_tables          # writes results/*.md
    python -m experiments.view_dependence.probe_tables --check  # exit 1 when a committed table differs

* ``stage0_view_dependence.md`` from ``log/stage0_view_dependence.json``;
* ``stage0_length.md`` from ``log/stage0_length.json``: the same per class over
  ``recon=fast_view_mild``'s length (iterations), on its glossy and metal scenes;
* ``patch_inference.md``: ``log/patch_inference/<mode>.json`` (``whole``, ``patch512``),
  per scene and the paired differences (95 % bootstrap CI over scenes); the same for a retrained
  model, ``patch_inference_<scores folder>_<run>.md``: its 512-point-patch scores
  ``log/patch_inference_retrained/<scores folder>__<run>.json`` against its committed
  whole-cloud Table 2 scores;
* ``cue_oracle.md`` from ``log/cue_oracle.json``;
* ``pair_highlights.md`` from ``log/pair_highlights.json``: per controlled pair, how
  many of each member's surface points show a highlight in the exact lattice renders;
* ``cue_oracle_curve.md`` from ``log/cue_oracle_curve.json``: the oracle's learning curve
  over training scenes, per feature set (with the neighbourhood features) and conditions;
* ``cue_oracle_pooled.md`` from ``log/cue_oracle_pooled.json``: the oracle with the
  object-pooled features, on the held-out scenes and on the controlled pairs;
* ``retraining.md``: the Table 2 scores of ``gspi-reproduce study=view_dependence table=2 scale=probe recon=<name>``
  (``results/scores/table2_probe_<name>/``) or of its checkpoints measured before the last
  step (``log/retraining/<name>.json``), one row per Stage 0 config;
* ``retraining_shipped.md``: the same at the shipped scale, Table 2's Full runs under ``recon=fast``
  (``results/table2/cpu/``) against ``scale=cpu_view``'s (``results/scores/table2_cpu_<recon>/``, or a
  checkpoint measured before its last step: ``log/retraining_shipped/<recon>_s<seed>.json``;
  ``<recon>`` = ``exact_<departures>``: trained and measured on the exact renders),
  with issue 52's held-out targets met or not;
* ``stage0_only.md``: the shipped Stage II unchanged behind another Stage 0, end to end: the demo's
  four scenes (``log/stage0_only/demo_<recon>.json`` against the committed demo run,
  results/table1/cpu/, whose assets are ``recon=fast``'s) and the controlled pairs
  (``log/stage0_only/controlled_pairs_<recon>.json`` against
  results/controlled_pairs/cpu/gspi_recon_fast.json).
* ``retrained_real_objects.md``: the 19 real objects end to end behind ``recon=fast_view_mild``
  (``log/retrained_real_objects/real_<scores folder>__<run>.json``, and no
  decomposition's ``real_no_decomposition.json`` on the same reconstructions) against the default
  checkpoint's card (``recon=fast``).
* ``guidance.md``: a retrained model's held-out scores under classifier-free guidance
  (``log/guidance/<scores folder>__<run>__g<scale>.json``, ``evaluate_points
  --guidance-scale``) against its committed unguided Table 2 scores, with issue 52's targets.
* ``inference_recon.md``: a retrained model behind another Stage 0 than the one it was trained
  behind (no retraining): its held-out scores on the 32 held-out scenes reconstructed by that Stage 0
  (``log/inference_recon/<scores folder>__<run>__<recon>.json``; ``<recon>`` = ``exact``:
  the exact renders) against its committed Table 2 scores, paired over (scene, seed); and end to
  end (demo, controlled pairs:
  ``log/inference_recon/demo_<scores folder>__<run>__<recon>.json``,
  ``controlled_pairs_...``) against its runs in ``retrained_end_to_end``.
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
STUDY = Path(__file__).resolve().parent
PROBES = STUDY / "log"  # the probes' committed scores
OUT = STUDY / "results"  # the tables this module writes
SCORES = STUDY / "results" / "scores"  # the study's Table 2 scores (gspi-reproduce study=view_dependence)
PRODUCT_SCORES = {"table2_cpu": ROOT / "results" / "table2" / "cpu"}  # the product's Table 2 scores (the shipped recipe)
CHANNELS = ("albedo", "roughness", "metallic")


def scores_file(folder: str, run: str) -> Path:
    """A run's committed Table 2 scores: the study's folder, or the product's (``table2_cpu``)."""
    own = SCORES / folder / run / "scores.json"
    return own if own.parent.is_dir() else PRODUCT_SCORES[folder] / run / "scores.json"


def scene_avg(per_scene: dict) -> dict[str, float]:
    return {s: float(np.mean([v[c]["psnr"] for c in CHANNELS])) for s, v in per_scene.items()}


def channel(per_scene: dict, name: str) -> dict[str, float]:
    return {s: float(v[name]["psnr"]) for s, v in per_scene.items()}


def is_multi_part(scene: str) -> bool:
    return "multipart" in scene


def is_metal_class(scene: str) -> bool:
    """A pool scene of the metal class: the pool names a scene ``p<index>_<shape>_<class>``."""
    return scene.endswith("_metal") and not scene.endswith("_painted_metal")


def mean_iou(runs: list[dict], keep=lambda scene: True) -> float:
    """Mean metal IoU of Stage II over the runs' scenes that ``keep`` and whose IoU is defined
    (metal in the ground truth or in the prediction)."""
    return float(np.mean([v for r in runs for s, v in r["metal_iou"]["stage2"].items() if v is not None and keep(s)]))


def fmt_ci(mean: float, lo: float, hi: float) -> str:
    return f"{mean:+.2f} [{lo:+.2f}, {hi:+.2f}]"


def patch_table(whole: dict, patch: dict, *, model: str = "The shipped checkpoint",
                scenes: str = "the metal class and the multi-part scenes") -> str:
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
                        ("metal IoU, metal class", is_metal_class),
                        ("metal IoU, multi-part scenes", is_multi_part)):
        a = {s: v for s, v in wi.items() if v is not None and keep(s)}
        b = {s: v for s, v in pi.items() if v is not None and keep(s)}
        both = sorted(set(a) & set(b))
        if both:
            out.append(f"| {label} ({len(both)}) | {np.mean([a[s] for s in both]):.2f} | "
                       f"{np.mean([b[s] for s in both]):.2f} | {fmt_ci(*paired_bootstrap_ci(b, a))} |")
    head = (f"{model} ({whole.get('checkpoint', '?')}) on {len(common)} held-out pool scenes "
            f"({whole['data']}: {scenes}), {whole['num_steps']} DDIM steps, "
            f"{whole.get('max_points')} points per scene.")
    return head + "\n\n" + "\n".join(out) + "\n\nPer scene:\n\n" + "\n".join(lines) + "\n"


def paired_difference(runs: list[dict], ref: list[dict]) -> dict[str, str]:
    """Paired mean difference [95 % CI] of ``runs`` minus ``ref`` over (scene, training seed): avg,
    roughness, metallic of the Stage II prediction."""
    a, b = by_seed(runs), by_seed(ref)
    seeds = sorted(set(a) & set(b))
    pair = lambda get, d: {(s, seed): v for seed in seeds for s, v in get(d[seed]).items()}  # noqa: E731
    return {name: fmt_ci(*paired_bootstrap_ci(pair(get, a), pair(get, b))) for name, get in (
        ("avg", scene_avg), ("roughness", lambda d: channel(d, "roughness")),
        ("metallic", lambda d: channel(d, "metallic")))}


def retraining_table(by_recon: dict[str, list[dict]]) -> str:
    """One row per Stage 0 config: its Full model's held-out channels, metal class and multi-part."""
    lines = ["| conditions (Stage 0 and departures) | training step | seeds | albedo | roughness | metallic | avg | roughness - no decomposition [95% CI] | metal IoU (scenes with metal) | metal IoU (metal class) | metal IoU (multi-part) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for recon, runs in by_recon.items():
        if not runs:
            continue
        ch = {c: np.mean([np.mean(list(channel(r["per_scene"]["stage2"], c).values())) for r in runs]) for c in CHANNELS}
        rough = {(s, i): v for i, r in enumerate(runs) for s, v in channel(r["per_scene"]["stage2"], "roughness").items()}
        base = {(s, i): v for i, r in enumerate(runs)
                for s, v in channel(r["per_scene"]["no_decomposition"], "roughness").items()}
        steps = ", ".join(str(r.get("checkpoint_step", "?")) for r in runs)
        lines.append(f"| {recon} | {steps} | {len(runs)} | {ch['albedo']:.2f} | {ch['roughness']:.2f} | {ch['metallic']:.2f} | "
                     f"{np.mean(list(ch.values())):.2f} | {fmt_ci(*paired_bootstrap_ci(rough, base))} | "
                     f"{mean_iou(runs):.2f} | {mean_iou(runs, is_metal_class):.2f} | {mean_iou(runs, is_multi_part):.2f} |")
    ref = by_recon.get("fast", [])
    for recon, runs in by_recon.items():
        seeds = sorted(set(by_seed(ref)) & set(by_seed(runs)))
        if recon == "fast" or not seeds:
            continue
        diff = paired_difference(runs, ref)
        over = "the held-out scenes" if len(seeds) == 1 else f"(scene, seed) over seeds {', '.join(map(str, seeds))}"
        lines += ["", f"{recon} - fast, paired over {over}: avg {diff['avg']}, roughness {diff['roughness']}, "
                      f"metallic {diff['metallic']} dB."]
    return "\n".join(lines) + "\n"


def by_seed(runs: list[dict]) -> dict[int, dict]:
    """{training seed: the run's per-scene Stage II scores}."""
    return {int(r.get("train_seed") or 0): r["per_scene"]["stage2"] for r in runs}


def targets_table(by_recon: dict[str, list[dict]]) -> str:
    """Issue 52's held-out targets per Stage 0 config: roughness above no decomposition with a
    paired 95 % CI above 0, metal class IoU >= 0.8, multi-part metal IoU >= 0.6 (all seeds pooled)."""
    lines = ["| conditions (Stage 0 and departures) | seeds | roughness CI above no decomposition | metal class IoU >= 0.8 | "
             "multi-part metal IoU >= 0.6 |", "|---|---|---|---|---|"]
    for recon, runs in by_recon.items():
        rough = {(s, i): v for i, r in enumerate(runs) for s, v in channel(r["per_scene"]["stage2"], "roughness").items()}
        base = {(s, i): v for i, r in enumerate(runs)
                for s, v in channel(r["per_scene"]["no_decomposition"], "roughness").items()}
        lo = paired_bootstrap_ci(rough, base)[1]
        iou, multi = mean_iou(runs, is_metal_class), mean_iou(runs, is_multi_part)
        mark = lambda ok, text: f"{'yes' if ok else 'no'} ({text})"  # noqa: E731
        lines.append(f"| {recon} | {len(runs)} | {mark(lo > 0, f'lower bound {lo:+.2f}')} | "
                     f"{mark(iou >= 0.8, f'{iou:.2f}')} | {mark(multi >= 0.6, f'{multi:.2f}')} |")
    return "\n".join(lines) + "\n"


DEMO = ROOT / "results" / "table1" / "cpu"
# GS-PI's recon=fast column: the demo run these probes were measured against (25 DDIM steps, Stage III
# 300 iterations; results/table1/cpu/method=gspi/eval/eval_meta.json as committed at b6c8cad), kept here
# since the demo's budget became 10 steps / 100 iterations (session 34): every column at one budget
GSPI_REFERENCE = ROOT / "experiments" / "view_dependence" / "log" / "stage0_only" / "reference_gspi_fast_300.json"
DEMO_CHANNELS = ("albedo", "roughness", "metallic", "relight")


def end_to_end_table(demo_runs: dict[str, dict], pairs: dict[str, dict], *,
                      intro: str = "the shipped Stage II", label=lambda name: f"recon={name}") -> str:
    """Per demo scene and channel: PSNR under recon=fast (the demo's committed run) and under each
    other run (``label(name)`` names its column), with no decomposition's; s004-style metal IoU; then
    the controlled-pair fractions."""
    meta = lambda method: json.loads((DEMO / f"method={method}" / "eval" / "eval_meta.json").read_text())["per_scene"]  # noqa: E731
    runs = {"fast": json.loads(GSPI_REFERENCE.read_text())["per_scene"], **{r: d["per_scene"] for r, d in demo_runs.items()}}
    nd = meta("no_decomposition")
    head = "| scene | channel | no decomposition | GS-PI, recon=fast | " + " | ".join(
        f"GS-PI, {label(r)}" for r in list(runs)[1:]) + " |"
    lines = [head, "|---" * (3 + len(runs)) + "|"]
    for scene in sorted(nd):
        for c in DEMO_CHANNELS:
            lines.append(f"| {scene} | {c} PSNR | {nd[scene][c]['psnr']:.2f} | "
                         + " | ".join(f"{v[scene][c]['psnr']:.2f}" for v in runs.values()) + " |")
        if nd[scene]["metallic"].get("iou") is not None or any(v[scene]["metallic"].get("iou") for v in runs.values()):
            lines.append(f"| {scene} | metal IoU | - | " + " | ".join(
                f"{v[scene]['metallic'].get('iou') or 0:.2f}" for v in runs.values()) + " |")
    for c in DEMO_CHANNELS:
        lines.append(f"| mean | {c} PSNR | {np.mean([nd[s][c]['psnr'] for s in nd]):.2f} | "
                     + " | ".join(f"{np.mean([v[s][c]['psnr'] for s in nd]):.2f}" for v in runs.values()) + " |")
    out = f"The demo's four `small` test scenes end to end (Stage III 300 iterations), {intro}:\n\n" + "\n".join(lines)
    if pairs:
        rows = ["| Stage 0 | glossy/matte pairs | ordered | ordered with gap >= 0.3 | metal/dielectric pairs | separated at 0.5 |",
                "|---|---|---|---|---|---|"]
        for recon, d in pairs.items():
            rows.append(f"| {'recon=fast' if recon == 'fast' else label(recon)} | {d['roughness']['pairs']} | "
                        f"{d['roughness']['ordered']:.2f} | {d['roughness']['ordered_with_gap']:.2f} | "
                        f"{d['metal']['pairs']} | {d['metal']['separated']:.2f} |")
        out += ("\n\nControlled pairs end to end at `small` (`benchmarks/bench_controlled_pairs.py`; the 6-pair set, "
                "`data.controlled_pairs.colours=1`):\n\n" + "\n".join(rows))
    return out + "\n"


def fast_pairs() -> dict:
    """The controlled-pairs benchmark of the shipped Stage II under recon=fast (committed)."""
    return json.loads((ROOT / "results" / "controlled_pairs" / "cpu" / "gspi_recon_fast.json").read_text())


def end_to_end_runs(folder: Path) -> tuple[dict[str, dict], dict[str, dict]]:
    """({name: demo run}, {name: controlled-pairs result}) of a folder's ``demo_<name>.json`` and
    ``controlled_pairs_<name>.json``, the pairs led by recon=fast's committed benchmark."""
    demo_runs = {p.stem.removeprefix("demo_"): json.loads(p.read_text()) for p in sorted(folder.glob("demo_*.json"))}
    pairs = {"fast": fast_pairs()}
    pairs.update({p.stem.removeprefix("controlled_pairs_"): json.loads(p.read_text())
                  for p in sorted(folder.glob("controlled_pairs_*.json"))})
    return demo_runs, (pairs if len(pairs) > 1 else {})


REAL_CHANNELS = ("albedo", "roughness", "metallic", "relight")


def real_objects_table(runs: dict[str, dict], no_decomposition: dict, card: dict, default: str) -> str:
    """Mean PSNR per channel over the real objects: the default's card (recon=fast) and each
    retrained model behind recon=fast_view_mild, each against no decomposition on its own Stage 0;
    "ahead" = above no decomposition on every channel's mean, relight included."""
    means = lambda per_scene: {c: float(np.mean([v[c]["psnr"] for v in per_scene.values()])) for c in REAL_CHANNELS}  # noqa: E731
    bottle = lambda per_scene: per_scene.get("WaterBottle", {}).get("metallic", {}).get("psnr")  # noqa: E731
    nd = means(no_decomposition["per_scene"])
    card_nd, n = card["no_decomposition_same_data"], len(no_decomposition["per_scene"])
    rows = [("no decomposition", "recon=fast", card_nd, None, None),
            (f"`{default}.pt` (default), seed 0", "recon=fast", card["seed0"]["mean_psnr"], card_nd,
             card["seed0"].get("WaterBottle_metallic_psnr")),
            ("no decomposition", "recon=fast_view_mild", nd, None, bottle(no_decomposition["per_scene"]))]
    for name, run in runs.items():
        if len(run["per_scene"]) != n:
            raise ValueError(f"real_{name}.json scores {len(run['per_scene'])} objects, no decomposition's {n}")
        rows.append(("retrained {}/{}".format(*name.split("__")), "recon=fast_view_mild", means(run["per_scene"]), nd,
                     bottle(run["per_scene"])))
    lines = ["| model | Stage 0 | " + " | ".join(f"{c} PSNR" for c in REAL_CHANNELS)
             + " | WaterBottle metallic PSNR | ahead of no decomposition on every channel |",
             "|---|---|" + "---|" * len(REAL_CHANNELS) + "---|---|"]
    for model, recon, m, base, wb in rows:
        verdict = "" if base is None else ("yes" if all(m[c] > base[c] for c in REAL_CHANNELS) else "no ("
                                           + ", ".join(c for c in REAL_CHANNELS if m[c] <= base[c]) + " behind)")
        lines.append(f"| {model} | {recon} | " + " | ".join(f"{m[c]:.2f}" for c in REAL_CHANNELS)
                     + f" | {'-' if wb is None else f'{wb:.2f}'} | {verdict} |")
    return (f"The {n} real objects (`gspi-data import.glb=../shared/data/real-objects preset=small`) end to end "
            "(Stage III 300 iterations, `+experiment=real_objects`): the default's card (`recon=fast`) and the Full "
            "models retrained under `recon=fast_view_mild` (retraining_shipped.md) behind that "
            "Stage 0, each against no decomposition on the same reconstructions. Test data only.\n\n"
            + "\n".join(lines) + "\n")


def oracle_curve_table(data: dict) -> str:
    """Per measure, rows (conditions, features) and a column per training-scene count."""
    by_row: dict[tuple[str, str], dict[int, dict]] = {}
    for key, sets in data["versions"].items():
        version, n = key.rsplit("@", 1)
        for fs, r in sets.items():
            by_row.setdefault((version, fs), {})[int(n)] = r
    sizes = sorted({n for cells in by_row.values() for n in cells})
    measures = [("metal-class IoU, per scene (Table 2's units; target 0.8)", lambda r: r.get("metal_iou_metal_class")),
                ("multi-part scenes' metal IoU, per scene (target 0.6)", lambda r: r.get("metal_iou_multi_part_scenes")),
                ("metal IoU, all test points pooled", lambda r: r["metal_iou"]),
                ("roughness PSNR minus the training-mean constant's (dB)",
                 lambda r: r["roughness_psnr"] - r["roughness_psnr_constant"])]
    out = [f"A per-point MLP ({data['steps']} steps, {data['points_per_scene']} points per scene) trained on the first n "
           "scenes of a seeded permutation of the 224 matte-pool training scenes and scored on the 32 held-out parts-pool "
           "scenes, on the exact renders' conditions and on `recon=fast_view_mild`'s. Features: R1 = Top-RGB + source-view "
           "one-hot; + cross-view = the per-point statistic over the lattice views (gspi/stage2/view_statistics.py); + "
           f"neighbourhood = the means of the statistic and of Top-RGB over each point's k = {data['neighbourhoods']} "
           "nearest points."]
    for title, get in measures:
        lines = [f"\n{title}:\n", "| conditions | features | " + " | ".join(f"n = {n}" for n in sizes) + " |",
                 "|---|---|" + "---|" * len(sizes)]
        for (version, fs), cells in by_row.items():
            vals = [get(cells[n]) if n in cells else None for n in sizes]
            lines.append(f"| {version} | {fs} | " + " | ".join("-" if v is None else f"{v:.2f}" for v in vals) + " |")
        out.append("\n".join(lines))
    return "\n".join(out) + "\n"


def oracle_pooled_table(data: dict) -> str:
    """Per conditions and feature set: the oracle's held-out measures and its verdicts on the
    controlled pairs under the same conditions."""
    pct = lambda v: "-" if v is None else f"{100 * v:.0f} %"  # noqa: E731
    lines = ["| conditions | features | metal-class IoU | multi-part metal IoU | roughness - constant (dB) | "
             "per scene [95 % CI] | glossy/matte ordered | ordered by >= 0.3 | metal/dielectric separated |",
             "|---|---|---|---|---|---|---|---|---|"]
    for version, sets in data["versions"].items():
        for fs, r in sets.items():
            pair = data.get("pairs", {}).get(version, {}).get(fs)
            verdicts = ([pct(pair["roughness"]["ordered"]), pct(pair["roughness"]["ordered_with_gap"]),
                         pct(pair["metal"]["separated"])] if pair else ["-"] * 3)
            lines.append(f"| {version} | {fs} | {r.get('metal_iou_metal_class', float('nan')):.2f} | "
                         f"{r.get('metal_iou_multi_part_scenes', float('nan')):.2f} | "
                         f"{r['roughness_psnr'] - r['roughness_psnr_constant']:+.2f} | "
                         + (fmt_ci(g["mean"], *g["ci95"]) if (g := r.get("roughness_scene_gain")) else "-") + " | "
                         + " | ".join(verdicts) + " |")
    n_pairs = next((f"{p['roughness']['pairs']} glossy/matte and {p['metal']['pairs']} metal/dielectric pairs"
                    for sets in data.get("pairs", {}).values() for p in sets.values()), "the controlled pairs")
    return (f"The per-point MLP of `cue_oracle_curve.md` ({data['steps']} steps, {data['points_per_scene']} points per "
            "scene) fitted on all 224 matte-pool training scenes, scored on the 32 held-out parts-pool scenes and on "
            f"{n_pairs} (`gspi-data preset=controlled_pairs`, seed 0) under the same conditions (exact renders, or "
            "each scene reconstructed by `recon=fast_view_mild`); a pair's verdicts are "
            "`benchmarks/bench_controlled_pairs.py`'s, from each scene's mean prediction over its surface points. "
            "+ object = the object's mean and 90th percentile of the cross-view statistic and its share of highlit "
            "points, the same for every point of it (`cue_oracle.object_features`). Roughness - constant: over all "
            "test points pooled; per scene: the mean over the held-out scenes of each scene's own PSNR minus the "
            "training-mean constant's, with its paired 95 % bootstrap CI (issue 52's roughness rule in the oracle's "
            "terms; - = not measured).\n\n" + "\n".join(lines) + "\n")


def pair_highlights_table(data: dict) -> str:
    """Per pair and member: the per-point gain's median and q90 and the share of highlit points; then
    the mean share per member kind."""
    lines = ["| pair | kind | family | member | median gain | q90 gain | points highlit |", "|---|---|---|---|---|---|---|"]
    share: dict[str, list[float]] = {}
    for p in data["pairs"]:
        for member, v in p["members"].items():
            lines.append(f"| {p['id']} | {p['kind']} | {p['family']} | {member} | {v['median']:.3f} | {v['q90']:.3f} | "
                         f"{100 * v['share_highlit']:.1f} % |")
            share.setdefault(member, []).append(v["share_highlit"])
    summary = ", ".join(f"{m} {100 * np.mean(v):.0f} % (min {100 * np.min(v):.0f} %)" for m, v in share.items())
    return (f"The exact lattice renders of each controlled pair ({data['points_per_scene']} surface points per scene): "
            "the per-point brightest-minus-median-view luminance gain, and the share of points whose gain exceeds "
            f"{data['highlight_gain']} (a visible highlight). Mean share of highlit points: {summary}.\n\n"
            + "\n".join(lines) + "\n")


def inference_recon_tables(folder: Path) -> str:
    """``inference_recon.md`` (see the module's docstring); "" when nothing is committed."""
    held: dict[tuple[str, str], list[tuple[str, dict]]] = {}  # (scores folder, recon) -> [(run, scores)]
    for p in sorted(folder.glob("*__*__*.json")):
        if p.name.startswith(("demo_", "controlled_pairs_")):
            continue
        scores_folder, run, recon = p.stem.split("__")
        held.setdefault((scores_folder, recon), []).append((run, json.loads(p.read_text())))
    parts = []
    for (scores_folder, recon), measured in held.items():
        ref = [json.loads(scores_file(scores_folder, run).read_text())
               for run, _ in measured]
        conditions = "the exact renders (no Stage 0)" if recon == "exact" else f"recon={recon}"
        rows = {f"{scores_folder}, behind its own Stage 0 (Table 2's runs)": ref,
                f"{scores_folder}, behind {conditions}": [m for _, m in measured]}
        diff = paired_difference([m for _, m in measured], ref)
        parts.append(
            f"{scores_folder} ({', '.join(run for run, _ in measured)}) measured on the 32 held-out scenes' conditions "
            f"from {conditions}, not retrained (`evaluate_points`, 10 DDIM steps, 20000 points):\n\n"
            + retraining_table(rows) + f"\n{conditions} - its own Stage 0, paired over (scene, seed): avg {diff['avg']}, "
            f"roughness {diff['roughness']}, metallic {diff['metallic']} dB.\n\n" + targets_table(rows))
    demo_runs, pairs = end_to_end_runs(folder)
    if demo_runs:  # led by the same models' runs behind their own Stage 0 (retrained_end_to_end), "<model>__own"
        own_runs, own_pairs = end_to_end_runs(PROBES / "retrained_end_to_end")
        models = sorted({name.rsplit("__", 1)[0] for name in demo_runs})
        runs = {**{f"{m}__own": own_runs[m] for m in models if m in own_runs}, **demo_runs}
        chosen = {**{f"{m}__own": own_pairs[m] for m in models if m in own_pairs},
                  **{n: pairs[n] for n in demo_runs if n in pairs}}
        parts.append(end_to_end_table(
            runs, {"fast": fast_pairs(), **chosen} if chosen else {}, intro="the shipped Stage II under recon=fast against retrained "
            "models behind the Stage 0 they were trained behind (`own`) and behind another (`recon=...`), not retrained",
            label=lambda name: "{}/{} behind {}".format(*name.split("__")[:2], "its own Stage 0" if name.endswith(
                "__own") else f"recon={name.split('__')[2]}")))
    return "\n".join(parts)


def tables() -> dict[str, str]:
    """{file name: markdown} of every probe whose scores are committed."""
    from experiments.view_dependence.stage0_probe import class_table

    out = {}
    stage0 = PROBES / "stage0_view_dependence.json"
    if stage0.is_file():
        out["stage0_view_dependence.md"] = class_table(json.loads(stage0.read_text()))
    length = PROBES / "stage0_length.json"  # the same probe over Stage 0's length, glossy and metal scenes
    if length.is_file():
        out["stage0_length.md"] = (
            "`recon=fast_view_mild` at 600 (its own), 1200 and 1800 iterations (`recon.iterations`, the "
            "schedule otherwise unchanged) on the Stage 0 probe's 2 glossy-plastic and 3 metal scenes: what a "
            "longer Stage 0 keeps of the exact renders' highlights (columns as in stage0_view_dependence.md; "
            "`_q90`: the 90th percentile of the per-point gain, where a glossy object's few highlit points show).\n\n"
            + class_table(dict(sorted(json.loads(length.read_text()).items(),  # by iterations: <recon>_<n>
                                      key=lambda kv: int(kv[0].rsplit("_", 1)[1]))), ("gt_q99", "asset_q99", "gt_peak_gain", "asset_peak_gain",
                                                           "gt_peak_gain_q90", "asset_peak_gain_q90", "lattice_db",
                                                           "heldout_db", "seconds")))
    whole, patch = PROBES / "patch_inference" / "whole.json", PROBES / "patch_inference" / "patch512.json"
    if whole.is_file() and patch.is_file():
        out["patch_inference.md"] = patch_table(json.loads(whole.read_text()), json.loads(patch.read_text()))
    for patch in sorted((PROBES / "patch_inference_retrained").glob("*__*.json")):  # <scores folder>__<run>.json
        folder, run = patch.stem.split("__")  # its whole-cloud scores: the run's committed Table 2 scores
        whole = scores_file(folder, run)
        out[f"patch_inference_{folder}_{run}.md"] = patch_table(
            json.loads(whole.read_text()), json.loads(patch.read_text()),
            model=f"{run} of `{folder}`, retrained at the shipped scale", scenes="all")
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
    highlights = PROBES / "pair_highlights.json"
    if highlights.is_file():
        out["pair_highlights.md"] = pair_highlights_table(json.loads(highlights.read_text()))
    curve = PROBES / "cue_oracle_curve.json"
    if curve.is_file():
        out["cue_oracle_curve.md"] = oracle_curve_table(json.loads(curve.read_text()))
    pooled = PROBES / "cue_oracle_pooled.json"
    if pooled.is_file():
        out["cue_oracle_pooled.md"] = oracle_pooled_table(json.loads(pooled.read_text()))
    by_recon: dict[str, list[dict]] = {}
    for p in sorted(SCORES.glob("table2_probe_*/full_s*/scores.json")):
        by_recon.setdefault(p.parent.parent.name.removeprefix("table2_probe_"), []).append(json.loads(p.read_text()))
    for p in sorted((PROBES / "retraining").glob("*.json")):  # runs measured before their last step (cut for time)
        by_recon.setdefault(p.stem, []).append(json.loads(p.read_text()))
    if by_recon:
        out["retraining.md"] = ("Full of the probe recipe (32 matte-pool scenes, cpu_pool224_pixel), trained under each "
                                "Stage 0's conditions and measured on the 32 held-out scenes reconstructed by the same "
                                "Stage 0 (10 DDIM steps, 20000 points).\n\n" + retraining_table(by_recon))
    shipped: dict[str, list[dict]] = {"fast": [json.loads(p.read_text()) for p in sorted(
        PRODUCT_SCORES["table2_cpu"].glob("full_s*/scores.json"))]}
    for p in sorted(SCORES.glob("table2_cpu_*/full_s*/scores.json")):
        shipped.setdefault(p.parent.parent.name.removeprefix("table2_cpu_"), []).append(json.loads(p.read_text()))
    for p in sorted((PROBES / "retraining_shipped").glob("*.json")):  # <recon>_s<seed>: measured before the last step
        shipped.setdefault(p.stem.rsplit("_s", 1)[0], []).append(json.loads(p.read_text()))
    if len(shipped) > 1:
        out["retraining_shipped.md"] = (
            "Full of the shipped recipe (224 matte-pool scenes, cpu_pool224_pixel_5k, 5000 steps): `gspi-reproduce "
            "table=2 scale=cpu` (recon=fast) against `scale=cpu_view` (recon=fast_view_mild) and its departures "
            "(`_xv`: + the cross-view condition, `scale=cpu_view_xv`; `_whole`: whole-object training items, "
            "`scale=cpu_view_whole`; conf/reproduce/), each measured on the 32 held-out parts-pool scenes reconstructed "
            "by its own Stage 0 (10 DDIM steps, 20000 points); `exact_...`: the same recipe trained and measured on the "
            "exact lattice renders, no Stage 0 (the ceiling of any Stage 0 for it); a run measured before its last step "
            "shows that step.\n\n" + retraining_table(shipped) + "\nIssue 52's held-out targets:\n\n"
            + targets_table(shipped))
    demo_runs, pairs = end_to_end_runs(PROBES / "stage0_only")
    if demo_runs:
        out["stage0_only.md"] = end_to_end_table(demo_runs, pairs)
    demo_runs, pairs = end_to_end_runs(PROBES / "retrained_end_to_end")  # <scores folder>__<run>: a retrained model
    if demo_runs or pairs:
        out["retrained_end_to_end.md"] = end_to_end_table(
            demo_runs, pairs, intro="the shipped Stage II under recon=fast against the Full models retrained at the "
            "shipped scale under `recon=fast_view_mild` (`retraining_shipped.md`; the column names "
            "the model's committed scores folder and run), each behind `recon=fast_view_mild`",
            label=lambda name: "retrained {}/{}".format(*name.split("__")))
    guided: dict[str, dict[str, list[dict]]] = {}
    for p in sorted((PROBES / "guidance").glob("*__*__g*.json")):  # <scores folder>__<run>__g<scale>
        folder, run, scale = p.stem.split("__")
        rows = guided.setdefault(f"{folder}/{run}", {"guidance 1 (Table 2's run)": [json.loads(
            scores_file(folder, run).read_text())]})
        rows[f"guidance {scale.removeprefix('g')}"] = [json.loads(p.read_text())]
    if guided:
        out["guidance.md"] = "\n".join(
            f"Classifier-free guidance on {model} (`evaluate_points --guidance-scale`, the 32 held-out scenes, "
            f"10 DDIM steps, 20000 points; guidance 1 = off, the committed Table 2 run):\n\n"
            + retraining_table(rows) + "\n" + targets_table(rows) for model, rows in guided.items())
    behind = inference_recon_tables(PROBES / "inference_recon")
    if behind:
        out["inference_recon.md"] = behind
    real = PROBES / "retrained_real_objects"
    if (real / "real_no_decomposition.json").is_file():
        from gspi.publish.docs import DEFAULT_MODEL

        card = json.loads((ROOT / "checkpoints" / f"{DEFAULT_MODEL}.json").read_text())["real_objects_19_small"]
        runs = {p.stem.removeprefix("real_"): json.loads(p.read_text()) for p in sorted(real.glob("real_*__*.json"))}
        out["retrained_real_objects.md"] = real_objects_table(
            runs, json.loads((real / "real_no_decomposition.json").read_text()), card, DEFAULT_MODEL)
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
