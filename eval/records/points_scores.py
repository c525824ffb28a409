"""Table 2's point-level `scores.json` (format "gspi-points-eval"): its writer and reader
(the Table 2 rows it becomes: ``eval.tables.sources``).

`python -m gspi.stage2.evaluate_points CKPT DATA OUT` writes `OUT/scores.json` (format
"gspi-points-eval"): Table 2's measure of one trained Stage II model on the GT point clouds
of a split, per scene, for the model ("stage2") and the no-decomposition baseline. With one
such folder per ablation (a CPU-scale Table 2 trained outside gspi-run, docs/log/diary.md),

    gspi-table runs/t2/*/eval_heldout out=runs/t2_tables table=table2

builds Table 2 from such folders.
"""
from __future__ import annotations

from pathlib import Path

from eval.common.errors import MissingInputError
from eval.common.layout import LayoutError, read_json_object

FORMAT = "gspi-points-eval"
VERSION = 1
SCORES_NAME = "scores.json"
MODEL_KEY, BASELINE_KEY = "stage2", "no_decomposition"


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
    from eval.common.atomic import write_json_atomic

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
