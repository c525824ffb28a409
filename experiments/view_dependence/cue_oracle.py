"""Issue 52's third probe: is metal (and gloss) separable point by point, from what conditions?

A per-point regressor on the inputs of the learnability ladder's R1 (the local condition: Top-RGB +
source-view one-hot) with and without the per-point cross-view statistic
(``gspi.stage2.view_statistics``: brightest minus median view, spread, the highlight's tint),
trained on half of a dataset's scenes and scored on the other half (two folds by scene, seeded),
on the conditions of one or more versions of the same scenes: the exact renders (GT) and Stage 0
reconstructions (``gspi.recon.reconstructed_pool`` folders). Per fold and version it reports the
held-out points' metallic IoU at 0.5 (all scenes with metal, and the multi-part ones alone) and
the roughness PSNR against the training mean's. Writes a JSON (committed: experiments/view_dependence/log/) and
prints markdown.

    python -m experiments.view_dependence.cue_oracle exact=HELDOUT32 fast=RHELD_FAST fast_view=RHELD_VIEW \
        --out experiments/view_dependence/log/cue_oracle.json

Two questions the first table left open (session 25), both from ``NAME=TRAIN_FOLDER,TEST_FOLDER``:

* **Does the per-point cue grow with data?** ``--train-scenes 32,64,128,224`` fits the oracle on
  nested prefixes of a seeded permutation of the training folder's scenes and scores each on the
  same test scenes: the learning curve behind any "needs more data" claim.
* **Does a part's cue need its neighbours?** The feature set ``+ neighbourhood`` adds the mean of the
  cross-view statistic and of Top-RGB over each point's k nearest surface points (k in
  ``NEIGHBOURHOODS``, geometry only, the scene's own subset): a point that shows no highlight in any
  lattice view can take its part's. If it lifts the metal IoU where per-point features stop, the
  decision is part-level and the fix is in how Stage II pools, not in the conditions.

    python -m experiments.view_dependence.cue_oracle exact=TRAIN_VIEW,HELDOUT_TEST \
        fast_view_mild=RTRAIN_VIEW_MILD,RHELDOUT_VIEW_MILD --train-scenes 32,64,128,224 --steps 5000 \
        --out experiments/view_dependence/log/cue_oracle_curve.json

A third question (session 26), for gloss: **is the cue there once pooled over the whole object?**
The controlled pairs' glossy member shows a highlight on a minority of its points
(``pair_highlights.py``), so no per-point reader orders a pair. The feature set ``+ object`` adds,
broadcast to every point, the object's mean and 90th percentile of the cross-view statistic and its
share of highlit points (``object_features``). A third folder per version, a controlled-pairs
dataset under the same conditions (``NAME=TRAIN,TEST,PAIRS``), scores the oracle fitted on all
training scenes on those pairs with the benchmark's own verdicts
(``benchmarks/bench_controlled_pairs.score_pairs``, each scene's mean over its subset points):

    python -m experiments.view_dependence.cue_oracle exact=TRAIN_VIEW,HELDOUT_TEST,PAIRS18 \
        fast_view_mild=RTRAIN_VIEW_MILD,RHELDOUT_VIEW_MILD,RPAIRS18_VIEW_MILD --steps 5000 \
        --out experiments/view_dependence/log/cue_oracle_pooled.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from torch import nn

from eval.common.layout import read_splits
from gspi.stage2.view_statistics import NEIGHBOURHOOD_KS as NEIGHBOURHOODS  # k nearest of the 3000 subset points

POINTS_PER_SCENE = 3000
FEATURE_SETS = {"R1": ("top_rgb", "onehot"), "R1 + cross-view": ("top_rgb", "onehot", "cross_view"),
                "R1 + cross-view + neighbourhood": ("top_rgb", "onehot", "cross_view",
                                                    *(f"{f}_knn{k}" for k in NEIGHBOURHOODS
                                                      for f in ("cross_view", "top_rgb"))),
                "R1 + cross-view + object": ("top_rgb", "onehot", "cross_view", "cross_view_object")}


def object_features(features: np.ndarray, peak_gain: np.ndarray) -> np.ndarray:
    """[n, 2d + 1] the same row for every point: the object's mean and 90th percentile of each of
    the ``features`` [n, d] and its share of highlit points by their ``peak_gain``
    (``pair_highlights.highlit_share``). Pooled over the whole object, so a point takes what its
    object shows anywhere: the condition that would carry gloss if a minority of points shows it."""
    from experiments.view_dependence.pair_highlights import highlit_share

    row = np.concatenate([features.mean(axis=0), np.quantile(features, 0.9, axis=0),
                          [highlit_share(peak_gain)]]).astype(np.float32)
    return np.broadcast_to(row, (len(features), len(row))).copy()


def scene_arrays(scene_dir: Path, seed: int = 0) -> dict[str, np.ndarray]:
    """A seeded subset of the scene's GT points with their conditions and targets."""
    from gspi.stage2.data import read_lattice_cameras, srgb_top_rgb
    from gspi.stage2.view_statistics import condition_features, cross_view_radiance, neighbourhood_mean
    from experiments.view_dependence.stage0_probe import lattice_images, surface_subset

    pts = surface_subset(scene_dir, POINTS_PER_SCENE, seed)
    _, cams = read_lattice_cameras(scene_dir)
    images, depth = lattice_images(scene_dir)
    xyz = pts["xyz"].astype(np.float64)
    stats = cross_view_radiance(images, depth, cams, xyz)
    gen = json.loads((scene_dir / "scene.json").read_text()).get("generator", {})
    arrays = {"top_rgb": srgb_top_rgb(pts["rgb"]), "cross_view": condition_features(stats)}
    arrays["cross_view_object"] = object_features(arrays["cross_view"], stats[:, 0])
    for k in NEIGHBOURHOODS:
        arrays.update({f"{f}_knn{k}": neighbourhood_mean(xyz, arrays[f], xyz, k)
                       for f in ("cross_view", "top_rgb")})
    return {**arrays, "onehot": np.eye(32, dtype=np.float32)[pts["view"]],
            "roughness": pts["roughness"].astype(np.float32), "metallic": pts["metallic"].astype(np.float32),
            "multi_part": np.full(len(xyz), "parts" in gen.get("material", {}))}


def fit_mlp(x: np.ndarray, y: np.ndarray, *, seed: int = 0, steps: int = 1500) -> nn.Module:
    """A 2-layer MLP regressing y [n, 2] in [0, 1] (sigmoid head), Adam, full-batch-ish minibatches.

    Not the ladder's ``PointMLP`` (experiments/ladder/regressors.py: 4 layers of 256, all five f0
    channels in [-1, 1]): the oracle asks only whether two channels are separable per point from a
    handful of inputs, so a small net fits its 3000 points per scene in seconds; its committed
    figures (experiments/view_dependence/log/cue_oracle.json) were measured with this one."""
    torch.manual_seed(seed)
    model = nn.Sequential(nn.Linear(x.shape[1], 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, y.shape[1]))
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    xt, yt = torch.from_numpy(x).float(), torch.from_numpy(y).float()
    gen = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        idx = torch.randint(len(xt), (2048,), generator=gen)
        loss = ((torch.sigmoid(model(xt[idx])) - yt[idx]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return model


def metal_iou(pred: np.ndarray, gt: np.ndarray) -> float | None:
    p, g = pred > 0.5, gt > 0.5
    union = np.count_nonzero(p | g)
    return None if union == 0 else float(np.count_nonzero(p & g) / union)


def mean_or_none(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / max(np.mean((pred - gt) ** 2), 1e-12)))


def evaluate(version: dict[str, dict], folds: list[tuple[list[str], list[str]]], *, steps: int = 1500,
             feature_sets: list[str] | None = None, predict: dict[str, dict] | None = None) -> dict:
    """``version``: {scene: arrays} holding every scene the folds name; ``feature_sets``: the names
    of ``FEATURE_SETS`` to fit (default all); ``predict``: {scene: arrays} of further scenes (the
    controlled pairs, one fold only) whose mean predicted roughness and metallic each feature set's
    model also reports, under ``"scene_means"``.

    Per feature set: the held-out points' metallic IoU pooled over all test points and over the
    multi-part scenes' points, the roughness PSNR (model, training-mean constant), and, in the units
    of Table 2's measure and issue 52's targets, the mean over scenes of each scene's own metal IoU
    for the pool's metal class and for the multi-part scenes (``metal_iou_metal_class``,
    ``metal_iou_multi_part_scenes``; a scene with no metal in truth or prediction has none), and
    ``roughness_scene_gain``: each test scene's own roughness PSNR minus the training-mean
    constant's, its mean over scenes and paired 95 % bootstrap CI (issue 52's roughness rule, in
    the oracle's terms: does the best per-point reader of these conditions beat a constant with a
    CI above 0?)."""
    from eval.stats import paired_bootstrap_ci
    from experiments.view_dependence.probe_tables import is_metal_class, is_multi_part

    if predict and len(folds) != 1:
        raise ValueError("predicting further scenes needs one fold (NAME=TRAIN,TEST versions)")
    out = {}
    for fs_name in feature_sets or FEATURE_SETS:
        keys = FEATURE_SETS[fs_name]
        rows, scene_means, rough_gain = [], {}, {}
        for train, test in folds:
            cat = lambda names, k: np.concatenate([version[n][k] for n in names])  # noqa: E731
            x_tr = np.concatenate([cat(train, k) for k in keys], axis=1)
            y_tr = np.stack([cat(train, "roughness"), cat(train, "metallic")], axis=1)
            model = fit_mlp(x_tr, y_tr, steps=steps)
            run = lambda arrays: torch.sigmoid(model(torch.from_numpy(  # noqa: E731
                np.concatenate([arrays[k] for k in keys], axis=1)).float())).numpy()
            with torch.no_grad():
                pred = run({k: cat(test, k) for k in keys})
                for name, arrays in (predict or {}).items():
                    mean = run(arrays).mean(axis=0)
                    scene_means[name] = {"roughness": float(mean[0]), "metallic": float(mean[1])}
            rough, metal, multi = cat(test, "roughness"), cat(test, "metallic"), cat(test, "multi_part")
            ends = np.cumsum([len(version[n]["metallic"]) for n in test])
            scene_iou = {n: metal_iou(pred[e - len(version[n]["metallic"]):e, 1], version[n]["metallic"])
                         for n, e in zip(test, ends)}
            constant = float(y_tr[:, 0].mean())
            rough_gain.update({n: psnr(pred[e - len(version[n]["roughness"]):e, 0], version[n]["roughness"])
                               - psnr(np.full_like(version[n]["roughness"], constant), version[n]["roughness"])
                               for n, e in zip(test, ends)})
            class_mean = lambda keep: mean_or_none([v for n, v in scene_iou.items() if v is not None and keep(n)])  # noqa: E731
            rows.append({"metal_iou": metal_iou(pred[:, 1], metal),
                         "metal_iou_multi_part": metal_iou(pred[multi, 1], metal[multi]),
                         "roughness_psnr": psnr(pred[:, 0], rough),
                         "roughness_psnr_constant": psnr(np.full_like(rough, y_tr[:, 0].mean()), rough),
                         "metal_iou_metal_class": class_mean(is_metal_class),
                         "metal_iou_multi_part_scenes": class_mean(is_multi_part)})
        out[fs_name] = {k: float(np.mean([r[k] for r in rows if r[k] is not None])) for k in rows[0]
                        if any(r[k] is not None for r in rows)}
        gain, lo, hi = paired_bootstrap_ci(rough_gain, dict.fromkeys(rough_gain, 0.0))
        out[fs_name]["roughness_scene_gain"] = {"mean": gain, "ci95": [lo, hi], "scenes": len(rough_gain)}
        if scene_means:
            out[fs_name]["scene_means"] = scene_means
    return out


def nested_subsets(names: list[str], sizes: list[int], seed: int) -> dict[int, list[str]]:
    """{n: the first n of a seeded permutation of ``names``} (sorted): each larger set holds the
    smaller ones, so a learning curve changes one thing, the number of training scenes."""
    if max(sizes) > len(names):
        raise ValueError(f"--train-scenes asks for {max(sizes)} training scenes, the folder has {len(names)}")
    order = [names[i] for i in np.random.default_rng(seed).permutation(len(names))]
    return {n: sorted(order[:n]) for n in sizes}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("versions", nargs="+",
                        help="NAME=FOLDER (two folds by scene) or NAME=TRAIN_FOLDER,TEST_FOLDER: one set of conditions")
    parser.add_argument("--out", type=Path, help="JSON; its versions not named here are kept")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=1500, help="MLP training steps (batches of 2048 points)")
    parser.add_argument("--train-scenes", default=None,
                        help="comma-separated training-scene counts: a learning curve (NAME=TRAIN,TEST versions only)")
    parser.add_argument("--feature-sets", default=None,
                        help=f"comma-separated names of {list(FEATURE_SETS)} to fit (default: all)")
    args = parser.parse_args(argv)
    feature_sets = args.feature_sets.split(",") if args.feature_sets else list(FEATURE_SETS)
    unknown = sorted(set(feature_sets) - set(FEATURE_SETS))
    if unknown:
        raise SystemExit(f"--feature-sets: no feature sets {unknown} (has {list(FEATURE_SETS)})")
    torch.set_num_threads(1)
    versions = {k: [Path(p) for p in v.split(",")] for k, v in (a.split("=", 1) for a in args.versions)}
    sizes = [int(n) for n in args.train_scenes.split(",")] if args.train_scenes else None
    if sizes and any(len(f) < 2 for f in versions.values()):
        raise SystemExit("--train-scenes needs NAME=TRAIN_FOLDER,TEST_FOLDER versions")
    if any(len(f) == 3 for f in versions.values()) and sizes and len(sizes) > 1:
        raise SystemExit("a PAIRS folder is scored by the oracle of one training-set size: give one --train-scenes")
    scenes = lambda folder: [n for s in ("train", "val", "test") for n in read_splits(folder).get(s, [])]  # noqa: E731
    result = {"points_per_scene": POINTS_PER_SCENE, "steps": args.steps, "neighbourhoods": list(NEIGHBOURHOODS),
              "versions": {}, "folds": {}}
    if args.out and args.out.is_file():  # a curve grows by versions over sessions: keep the others
        previous = json.loads(args.out.read_text())
        if (previous.get("steps"), previous.get("neighbourhoods")) != (args.steps, list(NEIGHBOURHOODS)):
            raise SystemExit(f"{args.out} was measured with other settings (steps, neighbourhoods): use another --out")
        result["versions"], result["folds"] = previous["versions"], previous["folds"]
        result["pairs"] = previous.get("pairs", {})
    lines = ["| conditions | training scenes | features | metal IoU | metal IoU (multi-part) | roughness PSNR | constant "
             "| metal-class IoU (per scene) |", "|---|---|---|---|---|---|---|---|"]
    for vname, folders in versions.items():
        if len(folders) == 1:  # two folds by scene, seeded
            names = scenes(folders[0])
            order = np.random.default_rng(args.seed).permutation(len(names))
            half = [sorted(names[i] for i in order[: len(names) // 2]), sorted(names[i] for i in order[len(names) // 2:])]
            runs = {len(half[0]): [(half[0], half[1]), (half[1], half[0])]}
            arrays = {n: scene_arrays(folders[0] / n, args.seed) for n in names}
        else:  # train on one dataset's scenes, score on the other's (and on a pairs dataset's)
            train, test = scenes(folders[0]), scenes(folders[1])
            subsets = nested_subsets(train, sizes, args.seed) if sizes else {len(train): train}
            runs = {n: [(subset, test)] for n, subset in subsets.items()}
            used = sorted(set().union(*subsets.values()))
            arrays = {**{n: scene_arrays(folders[0] / n, args.seed) for n in used},
                      **{n: scene_arrays(folders[1] / n, args.seed) for n in test}}
        pair_arrays = pairs = None
        if len(folders) == 3:
            from benchmarks.bench_controlled_pairs import score_pairs
            from gspi.data.controlled_pairs import read_manifest

            pairs = read_manifest(folders[2])
            pair_arrays = {n: scene_arrays(folders[2] / n, args.seed)
                           for n in sorted({s for p in pairs for s in p["scenes"].values()})}
        for n, folds in runs.items():
            key = vname if len(runs) == 1 and not sizes else f"{vname}@{n}"
            result["folds"][key] = folds
            fitted = evaluate(arrays, folds, steps=args.steps, feature_sets=feature_sets, predict=pair_arrays)
            if pairs is not None:  # the benchmark's verdicts on the pairs, per feature set
                result.setdefault("pairs", {})[key] = {**result.get("pairs", {}).get(key, {}), **{
                    fs: score_pairs(pairs, r.pop("scene_means")) for fs, r in fitted.items()}}
            result["versions"][key] = {**result["versions"].get(key, {}), **fitted}
            for fs, r in fitted.items():
                lines.append(f"| {vname} | {n} | {fs} | {r['metal_iou']:.2f} | {r['metal_iou_multi_part']:.2f} | "
                             f"{r['roughness_psnr']:.2f} | {r['roughness_psnr_constant']:.2f} | "
                             f"{r.get('metal_iou_metal_class', float('nan')):.2f} |")
            print(lines[-1], flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
