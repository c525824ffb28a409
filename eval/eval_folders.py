"""Plain `gspi-eval` folders (no gspi-run record) -> a `Sweep` of Table 1 rows.

`gspi-table runs/gspi/eval runs/r3dg/eval out=tables` tabulates evaluation folders that no
sweep wrote (baseline imports, hand-made predictions). Each complete folder (summary.json and
eval_meta.json, the last file gspi-eval writes) becomes one run of its method, so Table 1 has
one builder and one renderer (`eval.tables_sweep`, `eval.tables_render`) whichever way the
scores were made. Cells are means over (scene, run) units: per scene from eval_meta.json's
`per_scene`; several folders of one method are its repeated runs (numbered like seeds).
A folder written before `per_scene` existed counts as one unit (scene "*") from summary.json.
"""
from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from eval.errors import MissingInputError
from eval.layout import LayoutError, read_json_object
from eval.protocol_id import protocol_hash, recorded_protocol
from eval.sweep import (COLUMNS, RunRecord, Sweep, material_protocol_label, per_scene_rows,
                        runtime_min_rows)

TABLE = "table1"


def find_eval_folders(paths: list[str | Path]) -> tuple[list[Path], list[Path]]:
    """(complete, incomplete) gspi-eval folders below each path, recursively.

    Incomplete: summary.json without eval_meta.json, or a Hydra output folder (.hydra/) with
    neither summary.json nor result.json (killed before it wrote anything).
    """
    found, incomplete = set(), set()
    for p in map(Path, paths):
        if not p.exists():
            raise MissingInputError(f"{p}: run folder not found")
        found |= {s.parent for s in p.rglob("summary.json")}
        incomplete |= {h.parent for h in p.rglob(".hydra") if h.is_dir()
                       and not (h.parent / "summary.json").is_file()
                       and not (h.parent / "result.json").is_file()}
    complete = sorted(d for d in found if (d / "eval_meta.json").is_file())
    incomplete |= {d for d in found if not (d / "eval_meta.json").is_file()}
    if not complete:
        bad = sorted(incomplete)
        raise FileNotFoundError(f"no complete gspi-eval folder (summary.json + eval_meta.json) "
                                f"below {', '.join(map(str, paths))}"
                                + (f"; incomplete (killed?) folders: {', '.join(map(str, bad))}"
                                   if bad else ""))
    return complete, sorted(incomplete)


def read_summary(path: Path) -> dict:
    """summary.json, refused (naming the file) when empty, NaN-valued or wrongly typed: a NaN
    must not print as "--" (not modelled), an empty file is an evaluation of 0 images."""
    summary = read_json_object(path)
    if not summary:
        raise LayoutError(f"{path}: no channel scored (an evaluation of 0 images); re-run "
                          "gspi-eval, which now refuses such a prediction folder")
    for channel, scores in summary.items():
        if not isinstance(scores, dict):
            raise LayoutError(f"{path}: {channel} must be an object {{psnr, ssim, lpips}}, "
                              f"got {scores!r}")
        for metric, value in scores.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value):
                raise LayoutError(f"{path}: {channel}.{metric} must be a number, got {value!r}")
    return summary


def read_eval_meta(path: Path) -> dict:
    meta = read_json_object(path)
    if not isinstance(meta.get("protocol", {}), dict):
        raise LayoutError(f"{path}: protocol must be an object {{name, version}}")
    return meta


def _score_rows(folder: Path, summary: dict, meta: dict) -> list[dict]:
    """Per-scene material rows; a folder without `per_scene` is one unit, scene "*"."""
    if meta.get("per_scene") is not None:
        return per_scene_rows(meta["per_scene"], folder / "eval_meta.json", "material")
    return per_scene_rows({"*": summary}, folder / "summary.json", "material")


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
            raise ValueError(f"method {method!r}: its runs were scored on different scene "
                             "sets, so their mean would mix them:\n  " + "\n  ".join(lines))


def load_eval_folders(paths: list[str | Path]) -> Sweep:
    """Every complete gspi-eval folder below `paths` as a Table 1 run of its method."""
    complete, incomplete = find_eval_folders(paths)
    summaries = {f: read_summary(f / "summary.json") for f in complete}
    metas = {f: read_eval_meta(f / "eval_meta.json") for f in complete}
    check_same_scenes(metas)
    rows, records, protocols, counts, runs_of = [], [], {}, {}, {}
    for folder in complete:
        meta = metas[folder]
        method = str(meta.get("method", folder.name))
        seed = runs_of[method] = runs_of.get(method, -1) + 1
        protocol = recorded_protocol(meta)
        record = RunRecord(path=folder / "eval_meta.json", status="complete", error=None,
                           method=method, ablation="full", table=TABLE, seed=seed,
                           config_hash=protocol_hash(protocol), data=meta.get("data"),
                           scenes=tuple(meta.get("scenes") or ()), material_eval=folder,
                           points_eval=None, mtime=(folder / "eval_meta.json").stat().st_mtime)
        records.append(record)
        protocols[str(folder)], counts[str(folder)] = protocol, meta.get("counts") or {}
        own = {"method": method, "ablation": "full", "table": TABLE, "seed": seed,
               "config_hash": record.config_hash, "data": record.data or "", "run": str(folder),
               "protocol": material_protocol_label(meta)}
        rows += [dict(own, **r) for r in _score_rows(folder, summaries[folder], meta)
                 + runtime_min_rows(meta)]
    notes = ([f"Incomplete gspi-eval folder(s) left out (killed before eval_meta.json): "
              f"{', '.join(map(str, incomplete))}"] if incomplete else [])
    return Sweep(values=pd.DataFrame(rows, columns=COLUMNS), records=records, notes=notes,
                 protocols=protocols, counts=counts)
