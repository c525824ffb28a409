"""Where a table's rows come from when no gspi-run sweep wrote them: plain gspi-eval folders
(Table 1) and Table 2's point-level scores.json folders, each read through its format's module
(``eval.records.eval_folder``, ``eval.records.points_scores``) into a `Sweep`, so every table has
one builder and one renderer (`eval.tables.build`, `eval.tables.render`) whichever way the scores
were made.

Plain gspi-eval folders: `gspi-table runs/gspi/eval runs/r3dg/eval out=tables` tabulates
evaluation folders that no sweep wrote (baseline imports, hand-made predictions). Each complete
folder becomes one run of its method. Cells are means over (scene, run) units: per scene from
eval_meta.json's `per_scene`; several folders of one method are its repeated runs (numbered like
seeds). A folder written before `per_scene` existed counts as one unit (scene "*").

Points folders: each is one run of `gspi` with its checkpoint's ablation (runs of one ablation
with different training seeds are its seeds); the baseline is one more row ("No
decomposition"), taken once, because it does not depend on the model (the folders must agree).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pandas as pd

from eval.points_protocol import recorded_measure_hash
from eval.protocol_id import protocol_hash, recorded_protocol
from eval.records.eval_folder import META_NAME, SUMMARY_NAME, find_eval_folders, read_eval_meta, read_summary
from eval.records.points_scores import (BASELINE_KEY, FORMAT, MODEL_KEY, SCORES_NAME, find_points_folders,
                                        read_points_scores)
from eval.sweep import (COLUMNS, RunRecord, Sweep, SweepError, material_protocol_label, peak_memory_rows, per_scene_rows,
                        runtime_min_rows)
from eval.tables.build import TABLE_SPECS

TABLE1, TABLE2 = "table1", "table2"
# Table 2 as gspi-run measures it is on the GENERATED point cloud (Stage I on the 2DGS asset);
# these folders measure the model alone, on the scenes' GT point clouds: the table says so.
TABLE2_GT = replace(TABLE_SPECS[TABLE2], title="Table 2: Stage II ablations (GT point cloud, evaluate_points)",
                    averaging="per scene: mean over the 32 lattice views of the scene's GT point cloud "
                              "(gspi.stage2.evaluate_points), then over albedo, roughness, metallic")


# ---- plain gspi-eval folders -> Table 1 --------------------------------------------------------
def _score_rows(folder: Path, summary: dict, meta: dict) -> list[dict]:
    """Per-scene material rows; a folder without `per_scene` is one unit, scene "*"."""
    if meta.get("per_scene") is not None:
        return per_scene_rows(meta["per_scene"], folder / META_NAME, "material")
    return per_scene_rows({"*": summary}, folder / SUMMARY_NAME, "material")


def check_same_scenes(metas: dict[Path, dict]) -> None:
    """Refuse to average folders of one method scored on different scene sets (the error
    names the folders); folders without a recorded scene list are not compared."""
    by_method: dict[str, list[Path]] = {}
    for folder, meta in metas.items():
        by_method.setdefault(str(meta.get("method", folder.name)), []).append(folder)
    for method, folders in by_method.items():
        scenes = {tuple(sorted(metas[f].get("scenes") or [])) for f in folders}
        scenes.discard(())
        if len(scenes) > 1:
            lines = [f"{f}: {metas[f].get('scenes')}" for f in folders]
            raise SweepError(f"method {method!r}: its runs were scored on different scene "
                             "sets, so their mean would mix them:\n  " + "\n  ".join(lines))


def load_eval_folders(paths: list[str | Path]) -> Sweep:
    """Every complete gspi-eval folder below `paths` as a Table 1 run of its method."""
    complete, incomplete = find_eval_folders(paths)
    summaries = {f: read_summary(f / SUMMARY_NAME) for f in complete}
    metas = {f: read_eval_meta(f / META_NAME) for f in complete}
    check_same_scenes(metas)
    rows, records, protocols, counts, runs_of = [], [], {}, {}, {}
    for folder in complete:
        meta = metas[folder]
        method = str(meta.get("method", folder.name))
        seed = runs_of[method] = runs_of.get(method, -1) + 1
        protocol = recorded_protocol(meta)
        record = RunRecord(path=folder / META_NAME, status="complete", error=None,
                           method=method, ablation="full", table=TABLE1, seed=seed,
                           config_hash=protocol_hash(protocol), data=meta.get("data"),
                           scenes=tuple(meta.get("scenes") or ()), material_eval=folder,
                           points_eval=None, mtime=(folder / META_NAME).stat().st_mtime)
        records.append(record)
        protocols[str(folder)], counts[str(folder)] = protocol, meta.get("counts") or {}
        own = {"method": method, "ablation": "full", "table": TABLE1, "seed": seed,
               "config_hash": record.config_hash, "data": record.data or "", "run": str(folder),
               "protocol": material_protocol_label(meta)}
        rows += [dict(own, **r) for r in _score_rows(folder, summaries[folder], meta)
                 + runtime_min_rows(meta) + peak_memory_rows(meta)]
    notes = ([f"Incomplete gspi-eval folder(s) left out (killed before eval_meta.json): "
              f"{', '.join(map(str, incomplete))}"] if incomplete else [])
    return Sweep(values=pd.DataFrame(rows, columns=COLUMNS), records=records, notes=notes,
                 protocols=protocols, counts=counts)


# ---- Table 2's scores.json folders -----------------------------------------------------------
def _same_evaluation(scores: dict[Path, dict]) -> None:
    """All folders scored the same scenes of the same split and dataset, under the same measure
    (``eval.points_protocol``: its hash) and with the same baseline (else one table would compare
    models on different inputs)."""
    first_path, first = next(iter(scores.items()))
    summed = {p: d["checksums"] for p, d in scores.items() if (d.get("checksums") or {}).get("inputs")}
    if summed:  # recorded since session 27: the bytes each measure read
        ref_path, ref = next(iter(summed.items()))
        for path, sums in summed.items():
            if sums["inputs"] != ref["inputs"]:
                differ = sorted(n for n, c in sums["per_scene"].items() if c != ref["per_scene"].get(n))
                raise SweepError(f"{path} and {ref_path}: measured on different bytes of the same scenes (input "
                                 f"checksums differ for {len(differ)} scene(s), e.g. {', '.join(differ[:3])}: the "
                                 "data was rebuilt?); tabulate one evaluation at a time")
    ident = lambda d: (sorted(d["scenes"]), d["split"], d["data"], d.get("num_steps"),  # noqa: E731
                       d.get("max_points"), recorded_measure_hash(d))
    for path, data in scores.items():
        if ident(data) != ident(first):
            raise SweepError(f"{path} and {first_path}: scored on different scenes/split/data/DDIM "
                             f"steps/points/measure (eval.points_protocol hash) ({ident(data)} vs {ident(first)}); "
                             "tabulate one evaluation at a time")
        if not _close(data["per_scene"][BASELINE_KEY], first["per_scene"][BASELINE_KEY]):
            raise SweepError(f"{path} and {first_path}: the no-decomposition baseline differs "
                             "(different training constants?); tabulate one evaluation at a time")


def _close(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-9) or (a != a and b != b)


def load_points_folders(paths: list[str | Path]) -> Sweep:
    """Every gspi-points-eval folder below `paths` as a Table 2 run of its ablation."""
    folders = find_points_folders(paths)
    if not folders:
        raise FileNotFoundError(f"no {SCORES_NAME} of format {FORMAT!r} below "
                                f"{', '.join(map(str, paths))}")
    return points_sweep({f / SCORES_NAME: read_points_scores(f / SCORES_NAME) for f in folders})


def points_sweep(scores: dict[Path, dict], *, seed_key: str | None = None) -> Sweep:
    """Table 2's Sweep of read gspi-points-eval files ({scores file: its data}): one run per file.

    Args:
        seed_key: the key holding each run's training seed (e.g. "train_seed", as
            results/heldout/cpu/*/scores.json carry it), so Δ pairs runs of one seed; None numbers the
            runs of each ablation 0, 1, ... in file order.
    """
    _same_evaluation(scores)
    rows, records, runs_of = [], [], {}
    label = f"{FORMAT} v{next(iter(scores.values())).get('version', 1)}"
    for path, data in scores.items():
        ablation = str(data["ablation"])
        seed = runs_of[ablation] = runs_of.get(ablation, -1) + 1
        if seed_key is not None:
            seed = int(data[seed_key])
        model = str(data.get("checkpoint", ""))  # a trained model's identity: its checkpoint
        rows += _rows("gspi", ablation, seed, model, path, data, MODEL_KEY, label)
        records.append(_record("gspi", ablation, seed, model, path, data))
    first_path, first = next(iter(scores.items()))
    rows += _rows(BASELINE_KEY, "full", 0, "", first_path, first, BASELINE_KEY, label)
    records.append(_record(BASELINE_KEY, "full", 0, "", first_path, first))
    notes = [f"{len(scores)} Stage II model(s) scored on the GT point clouds of "
             f"{len(first['scenes'])} {first['split']} scene(s) of {first['data']} "
             f"({first.get('num_steps')} DDIM steps, "
             f"{'every point' if first.get('max_points') is None else str(first['max_points']) + '-point subset + 1-NN fill'}"
             f" per scene); the no-decomposition row is the same for every "
             f"folder (training-mean roughness/metallic: {first.get('baseline_constants')})"]
    return Sweep(values=pd.DataFrame(rows, columns=COLUMNS), records=records, notes=notes,
                 specs={TABLE2: TABLE2_GT})


def _record(method: str, ablation: str, seed: int, model: str, path: Path, data: dict) -> RunRecord:
    return RunRecord(path=path, status="complete", error=None, method=method, ablation=ablation,
                     table=TABLE2, seed=seed, config_hash=model,
                     data=str(data["data"]), scenes=tuple(data["scenes"]), material_eval=None,
                     points_eval=path.parent, mtime=path.stat().st_mtime)


def _rows(method: str, ablation: str, seed: int, model: str, path: Path, data: dict, key: str,
          protocol: str) -> list[dict]:
    own = {"method": method, "ablation": ablation, "table": TABLE2, "seed": seed, "config_hash": model,
           "data": str(data["data"]), "run": str(path.parent), "protocol": protocol}
    return [dict(own, **r) for r in per_scene_rows(data["per_scene"][key], path, "points")]
