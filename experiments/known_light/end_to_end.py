"""Not an inverse crime (issue 66, item 6): `method=light_fit` end to end beside GS-PI's default
and no decomposition on inputs the read-out's split-sum shader did not make or lights it cannot
pick (``results/end_to_end.md``, finding 29).

Each variant is one `gspi-run -m` of the three methods (run.sh), Stage 0 (`recon=fast`)
reconstructing every asset from that variant's photos, scored by gspi-eval's default protocol:

- ``splitsum``: the demo's 4 `small` test scenes as README Table 1 has them (the committed
  ``results/table1/cpu``; its assets are the shipped ones, made by the same Stage 0 from the same photos);
- ``pathtraced``: the same scenes path-traced (`data.renderer=pathtraced`: shadows, interreflection);
- ``polyhaven_capture``: the same scenes captured under real HDRIs (`data.capture_envs=polyhaven`),
  none of which is among light_fit's candidates (`method.candidates: procedural`);
- ``polyhaven_capture_refined``: light_fit alone on the same runs' data with `method.light_refine=true`
  (``gspi.light.refine``), against the others of ``polyhaven_capture``;
- ``polyhaven_capture_in_set``: the same with the lights in the candidate set (`method.candidates=polyhaven`,
  whose capture HDRIs lit them): what the candidate set costs;
- ``polyhaven_capture_in_set_128``: the same with the candidates' maps at 128 rows, the rows the photos
  were shaded with (`method.env_height=128`; shipped 64): what the map's resolution costs under real lights;
- ``real_objects``: the 19 real glTF objects (`small`; light_fit and no decomposition; GS-PI's
  default from its card, `checkpoints/stage2_pool224_pixel_5k.json`).

The learned candidates on the same inputs (``PRIORS``: a variant whose `method=gspi` run is GS-PI
with one of the study's priors at step 5000, read as its posterior mean; the other methods from the
variant it repeats). Finding 30's metal-gate recipe behind the shipped assets, seed 0:

- ``polyhaven_capture_prior``: the real-HDRI capture (`polyhaven_capture`'s data and assets);
- ``pathtraced_prior``: the path-traced photos (`pathtraced`'s data, its assets reconstructed again);
- ``real_objects_prior``: the 19 real objects (`+experiment=real_objects`'s budgets; GS-PI's default
  from its card, means only).

Finding 35's candidate (the held-out-keys prior of finding 34, its roughness correction halved):
``real_objects_hk_x05`` (seed 0) and ``splitsum_hk_x05_s<seed>`` (the demo's 4 scenes and assets,
README Table 1's other runs): issue 42's end-to-end checks; ``real_objects_hk_x1``: the same prior as
trained (what halving its roughness correction does on the real objects); ``*_hk_x05_m0*``: the
candidate without its metallic correction (the read-out's metallic).

    python -m experiments.known_light.end_to_end collect VARIANT RUNS   # copy a run's scores here
    python -m experiments.known_light.end_to_end                        # print the table
    python -m experiments.known_light.tables                            # write it (results/end_to_end.md)
"""
from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from eval.portable import portable

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
OUT = HERE / "results" / "end_to_end"
TABLE1 = ROOT / "results" / "table1" / "cpu"  # the split-sum variant: README Table 1's committed runs
METHODS = ("gspi", "no_decomposition", "light_fit")
REFERENCE = {"polyhaven_capture_refined": "polyhaven_capture", "polyhaven_capture_in_set": "polyhaven_capture",
             "polyhaven_capture_in_set_128": "polyhaven_capture"}  # a variant's missing methods: from this one
CHANNELS = ("albedo", "roughness", "metallic", "relight")
VARIANTS = {
    "splitsum": "the demo's 4 `small` test scenes, split-sum photos (README Table 1)",
    "pathtraced": "the same scenes path-traced (`data.renderer=pathtraced`), assets reconstructed from them",
    "polyhaven_capture": "the same scenes captured under real HDRIs in no candidate set (`data.capture_envs=polyhaven`)",
    "polyhaven_capture_refined": "the same, light_fit refining the light (`method.light_refine=true`)",
    "polyhaven_capture_in_set": "the same, light_fit's candidates the real HDRIs' set (`method.candidates=polyhaven`)",
    "polyhaven_capture_in_set_128": "the same, the candidates' maps at the photos' 128 rows (`method.env_height=128`)",
    "real_objects": "the 19 real glTF objects (`small`, split-sum photos)",
}
PRIOR = "metal-gate prior (seed 0)"   # finding 30's prior, as its PRIORS variants' method=gspi run is named
CANDIDATE = "finding 35's candidate (seed {seed})"  # the held-out-keys prior, roughness correction x 0.5
CANDIDATE_M0 = "finding 35's candidate, no metallic correction (seed 0)"
PRIORS = {  # variant: (the variant whose data it repeats, how its method=gspi run is named)
    "polyhaven_capture_prior": ("polyhaven_capture", PRIOR), "pathtraced_prior": ("pathtraced", PRIOR),
    "real_objects_prior": ("real_objects", PRIOR),
    "real_objects_hk_x05": ("real_objects", CANDIDATE.format(seed=0)),
    "real_objects_hk_x1": ("real_objects", "finding 34's prior as trained (seed 0)"),
    "splitsum_hk_x05_m0_s0": ("splitsum", CANDIDATE_M0), "real_objects_hk_x05_m0": ("real_objects", CANDIDATE_M0),
    "splitsum_hk_x05_s0": ("splitsum", CANDIDATE.format(seed=0)),
    "splitsum_hk_x05_s1": ("splitsum", CANDIDATE.format(seed=1)),
}


def collect(variant: str, runs: Path) -> list[Path]:
    """Copies each method's eval/summary.json and eval/eval_meta.json of a `gspi-run -m` folder
    (its job folder named by its overrides, ``method=<name>`` among them: ``runs/<job>/eval``) under
    results/end_to_end/<variant>/method=<name>/, paths made portable."""
    written = []
    jobs = [d for d in Path(runs).iterdir() if d.is_dir()] if Path(runs).is_dir() else []
    for method in METHODS:
        found = [d / "eval" for d in jobs if f"method={method}" in d.name.split(",")]
        if len(found) != 1 or not (found[0] / "eval_meta.json").is_file():
            continue
        src = found[0]
        for name in ("summary.json", "eval_meta.json"):
            data = portable(json.loads((src / name).read_text()), {"<work>": Path(runs).parent})
            dst = OUT / variant / f"method={method}" / "eval" / name
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
            written.append(dst)
    if not written:
        raise SystemExit(f"{runs}: no method=<name>/eval/eval_meta.json of {METHODS}")
    return written


def eval_dir(variant: str, method: str) -> Path:
    """Where a method's committed eval files of a variant lie (the split-sum variant: README Table 1's)."""
    return (TABLE1 if variant == "splitsum" else OUT / variant) / f"method={method}" / "eval"


def per_scene(variant: str, method: str) -> dict | None:
    """{scene: {channel: PSNR}} of a method in a variant, or None where it was not run."""
    path = eval_dir(variant, method) / "eval_meta.json"
    if not path.is_file():
        return None
    return {scene: {c: row[c]["psnr"] for c in CHANNELS if c in row}
            for scene, row in json.loads(path.read_text())["per_scene"].items()}


def metal_iou(variant: str, method: str) -> float | None:
    path = eval_dir(variant, method) / "summary.json"
    return json.loads(path.read_text())["metallic"].get("iou") if path.is_file() else None


def card_row() -> dict[str, float]:
    """GS-PI's default on the 19 real objects, seed 0, from its card."""
    card = json.loads((ROOT / "checkpoints" / "stage2_pool224_pixel_5k.json").read_text())
    return card["real_objects_19_small"]["seed0"]["mean_psnr"]


def lead(a: dict, b: dict, channel: str) -> tuple[float, int, int]:
    """(mean a - b over the scenes both have, scenes where a is ahead, scenes)."""
    diffs = [a[s][channel] - b[s][channel] for s in a if s in b and channel in a[s] and channel in b[s]]
    return statistics.fmean(diffs), sum(d > 0 for d in diffs), len(diffs)


def table() -> str:
    lines = ["# light_fit end to end on inputs the read-out's shader did not make (issue 66, item 6)", "",
             "gspi-eval's default protocol, mean PSNR (dB) over the scenes; Stage 0 `recon=fast` from each variant's "
             "photos; the demo's budgets (`+experiment=demo`: GS-PI 10 DDIM steps, 2 points per Gaussian). Lead: "
             "light_fit minus the other, mean over scenes (scenes ahead / scenes). Generated by "
             "`python -m experiments.known_light.end_to_end` from results/end_to_end/ and results/table1/cpu.", "",
             "| variant | method | albedo | roughness | metallic | relight | metal IoU |", "|---|---|---|---|---|---|---|"]
    leads = ["", "| variant | light_fit minus | albedo | roughness | metallic | relight |", "|---|---|---|---|---|---|"]
    for variant, caption in VARIANTS.items():
        scores = {m: per_scene(variant, m) for m in METHODS}
        if scores["light_fit"] is None:
            continue
        for method, rows in scores.items():
            if rows is None:
                if method == "gspi" and variant == "real_objects":
                    card = card_row()
                    lines.append(f"| {caption} | gspi (its card, seed 0) | " +
                                 " | ".join(f"{card[c]:.2f}" for c in CHANNELS) + " | |")
                continue
            means = [statistics.fmean(r[c] for r in rows.values()) for c in CHANNELS]
            iou = metal_iou(variant, method)
            lines.append(f"| {caption} ({len(rows)} scenes) | {method} | " + " | ".join(f"{v:.2f}" for v in means) +
                         f" | {'' if iou is None else f'{iou:.2f}'} |")
        others = {m: scores[m] for m in ("gspi", "no_decomposition")}
        if variant in REFERENCE:
            others = {m: per_scene(REFERENCE[variant], m) for m in METHODS}
            others = {(f"light_fit of {REFERENCE[variant]}" if m == "light_fit" else m): v for m, v in others.items()}
        if variant == "real_objects":  # GS-PI from its card: means only
            mine, card = [statistics.fmean(r[c] for r in scores["light_fit"].values()) for c in CHANNELS], card_row()
            leads.append(f"| {variant} | gspi (its card, seed 0; means only) | " +
                         " | ".join(f"{m - card[c]:+.2f}" for m, c in zip(mine, CHANNELS)) + " |")
        for other, rows in others.items():
            if rows is None:
                continue
            cells = [lead(scores["light_fit"], rows, c) for c in CHANNELS]
            leads.append(f"| {variant} | {other} | " + " | ".join(f"{d:+.2f} ({k}/{n})" for d, k, n in cells) + " |")
    return "\n".join(lines + leads + prior_table()) + "\n"


def prior_table() -> list[str]:
    """The learned candidate's rows (PRIORS) and its lead over the others on the same data."""
    lines = ["", "The study's learned candidates (GS-PI with finding 30's metal-gate prior, or finding 35's "
             "candidate: step 5000, one DDIM step) on the same data and assets. Lead: the prior minus the other, "
             "mean over scenes (scenes ahead / scenes).", "",
             "| variant | method | albedo | roughness | metallic | relight | metal IoU |",
             "|---|---|---|---|---|---|---|"]
    leads, measured = ["", "| variant | the prior minus | albedo | roughness | metallic | relight |", "|---|---|---|---|---|---|"], []
    for variant, (reference, name_of_prior) in PRIORS.items():
        mine = per_scene(variant, "gspi")
        if mine is None:
            continue
        means = [statistics.fmean(r[c] for r in mine.values()) for c in CHANNELS]
        iou = metal_iou(variant, "gspi")
        measured.append(variant)
        lines.append(f"| {VARIANTS[reference]} ({len(mine)} scenes) | {name_of_prior} | " +
                     " | ".join(f"{v:.2f}" for v in means) + f" | {'' if iou is None else f'{iou:.2f}'} |")
        if reference == "real_objects":  # GS-PI's default from its card: means only
            card = card_row()
            leads.append(f"| {variant} | GS-PI's default (its card, seed 0; means only) | " +
                         " | ".join(f"{m - card[c]:+.2f}" for m, c in zip(means, CHANNELS)) + " |")
        for other in METHODS:
            rows = per_scene(reference, other)
            if rows is None:
                continue
            cells = [lead(mine, rows, c) for c in CHANNELS]
            name = "GS-PI's default" if other == "gspi" else other
            leads.append(f"| {variant} | {name} | " + " | ".join(f"{d:+.2f} ({k}/{n})" for d, k, n in cells) + " |")
    return lines + leads if measured else []



def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("action", nargs="?", choices=("collect", "table"), default="table")
    parser.add_argument("variant", nargs="?", choices=tuple(VARIANTS) + tuple(PRIORS))
    parser.add_argument("runs", nargs="?", type=Path)
    args = parser.parse_args(argv)
    if args.action == "collect":
        if args.variant is None or args.runs is None:
            parser.error("collect VARIANT RUNS")
        for path in collect(args.variant, args.runs):
            print(f"wrote {path.relative_to(ROOT)}")
    print(table(), end="")  # results/end_to_end.md is written by `python -m experiments.known_light.tables`


if __name__ == "__main__":
    main()
