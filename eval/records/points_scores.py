"""Table 2's point-level `scores.json` (format "gspi-points-eval"): its writer, reader and the
`Sweep` of Table 2 rows it becomes.

`python -m gspi.stage2.evaluate_points CKPT DATA OUT` writes `OUT/scores.json` (format
"gspi-points-eval"): Table 2's measure of one trained Stage II model on the GT point clouds
of a split, per scene, for the model ("stage2") and the no-decomposition baseline. With one
such folder per ablation (a CPU-scale Table 2 trained outside gspi-run, docs/RESULTS.md),

    gspi-table runs/t2/*/eval_heldout out=runs/t2_tables table=table2

builds Table 2 with the one builder and renderer (`eval.tables.build`, `eval.tables.render`):
each folder is one run of `gspi` with its checkpoint's ablation (runs of one ablation with
different training seeds are its seeds); the baseline is one more row ("No decomposition"),
taken once, because it does not depend on the model (the folders must agree on it).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pandas as pd

from eval.errors import MissingInputError
from eval.layout import LayoutError, read_json_object
from eval.sweep import COLUMNS, RunRecord, Sweep, per_scene_rows
from eval.tables.build import TABLE_SPECS

FORMAT = "gspi-points-eval"
VERSION = 1
SCORES_NAME = "scores.json"
TABLE = "table2"
MODEL_KEY, BASELINE_KEY = "stage2", "no_decomposition"
# Table 2 as gspi-run measures it is on the GENERATED point cloud (Stage I on the 2DGS asset);
# these folders measure the model alone, on the scenes' GT point clouds: the table says so.
TABLE2_GT = replace(TABLE_SPECS[TABLE], title="Table 2: Stage II ablations (GT point cloud, evaluate_points)",
                    averaging="per scene: mean over the 32 lattice views of the scene's GT point cloud "
                              "(gspi.stage2.evaluate_points), then over albedo, roughness, metallic")


def find_points_folders(paths: list[str | Path]) -> list[Path]:
    """Folders below `paths` (recursively) whose scores.json has format gspi-points-eval."""
    found = []
    for p in map(Path, paths):
        if not p.exists():
            raise MissingInputError(f"{p}: run folder not found")
        for s in p.rglob(SCORES_NAME):
            if s.is_file() and _is_points_scores(s):
                found.append(s.parent)
    return sorted(set(found))


def write_points_scores(out_dir: str | Path, result: dict) -> Path:
    """``<out_dir>/scores.json`` with this format's name and version, atomically (NaN allowed:
    a channel the protocol cannot score)."""
    from eval.atomic import write_json_atomic

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return write_json_atomic(out_dir / SCORES_NAME, {**result, "format": FORMAT, "version": VERSION},
                             allow_nan=True)


def _is_points_scores(path: Path) -> bool:
    try:
        return read_json_object(path, what="scores.json").get("format") == FORMAT
    except LayoutError:  # not JSON / not an object: some other tool's scores.json
        return False


def read_points_scores(path: Path) -> dict:
    """One scores.json, checked: the fields the table needs, with the file named on error."""
    data = read_json_object(path, error=ValueError, what="scores.json of a Stage II point-cloud evaluation")
    for key in ("ablation", "per_scene", "scenes", "split", "data"):
        if key not in data:
            raise ValueError(f"{path}: lacks {key!r} (written by an older evaluate_points? rerun "
                             "python -m gspi.stage2.evaluate_points)")
    for key in (MODEL_KEY, BASELINE_KEY):
        if not isinstance(data["per_scene"].get(key), dict) or not data["per_scene"][key]:
            raise ValueError(f"{path}: per_scene.{key} must be a non-empty {{scene: ...}} object")
    return data


def _same_evaluation(scores: dict[Path, dict]) -> None:
    """All folders scored the same scenes of the same split and dataset, with the same
    baseline (else one table would compare models on different inputs)."""
    first_path, first = next(iter(scores.items()))
    ident = lambda d: (sorted(d["scenes"]), d["split"], d["data"], d.get("num_steps"),  # noqa: E731
                       d.get("max_points"))
    for path, data in scores.items():
        if ident(data) != ident(first):
            raise ValueError(f"{path} and {first_path}: scored on different scenes/split/data/DDIM "
                             f"steps/points ({ident(data)} vs {ident(first)}); tabulate one evaluation at a time")
        if not _close(data["per_scene"][BASELINE_KEY], first["per_scene"][BASELINE_KEY]):
            raise ValueError(f"{path} and {first_path}: the no-decomposition baseline differs "
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
    scores = {f: read_points_scores(f / SCORES_NAME) for f in folders}
    _same_evaluation(scores)
    rows, records, runs_of = [], [], {}
    label = f"{FORMAT} v{next(iter(scores.values())).get('version', 1)}"
    for folder, data in scores.items():
        ablation = str(data["ablation"])
        seed = runs_of[ablation] = runs_of.get(ablation, -1) + 1
        model = str(data.get("checkpoint", ""))  # a trained model's identity: its checkpoint
        rows += _rows("gspi", ablation, seed, model, folder, data, MODEL_KEY, label)
        records.append(_record("gspi", ablation, seed, model, folder, data))
    first_folder, first = next(iter(scores.items()))
    rows += _rows(BASELINE_KEY, "full", 0, "", first_folder, first, BASELINE_KEY, label)
    records.append(_record(BASELINE_KEY, "full", 0, "", first_folder, first))
    notes = [f"{len(folders)} Stage II model(s) scored on the GT point clouds of "
             f"{len(first['scenes'])} {first['split']} scene(s) of {first['data']} "
             f"({first.get('num_steps')} DDIM steps, "
             f"{'every point' if first.get('max_points') is None else str(first['max_points']) + '-point subset + 1-NN fill'}"
             f" per scene); the no-decomposition row is the same for every "
             f"folder (training-mean roughness/metallic: {first.get('baseline_constants')})"]
    return Sweep(values=pd.DataFrame(rows, columns=COLUMNS), records=records, notes=notes,
                 specs={TABLE: TABLE2_GT})


def _record(method: str, ablation: str, seed: int, model: str, folder: Path, data: dict) -> RunRecord:
    path = folder / SCORES_NAME
    return RunRecord(path=path, status="complete", error=None, method=method, ablation=ablation,
                     table=TABLE, seed=seed, config_hash=model,
                     data=str(data["data"]), scenes=tuple(data["scenes"]), material_eval=None,
                     points_eval=folder, mtime=path.stat().st_mtime)


def _rows(method: str, ablation: str, seed: int, model: str, folder: Path, data: dict, key: str,
          protocol: str) -> list[dict]:
    own = {"method": method, "ablation": ablation, "table": TABLE, "seed": seed, "config_hash": model,
           "data": str(data["data"]), "run": str(folder), "protocol": protocol}
    return [dict(own, **r) for r in per_scene_rows(data["per_scene"][key], folder / SCORES_NAME, "points")]
