"""The gspi-eval folder, one format with one owner: what `gspi-eval` writes and what
`gspi-table` and `gspi-run`'s sweep reader read (per_view.csv, eval_meta.json, summary.json
LAST: its presence means the other two belong to the same evaluation; docs/RELIABILITY.md).
How plain folders become Table 1 rows: ``eval.tables.sources``.
"""
from __future__ import annotations

import json
import math
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import pandas as pd

from eval.common.atomic import write_text_atomic
from eval.common.errors import MissingInputError
from eval.common.layout import LayoutError, read_json_object
from eval.records.run_record import RECORD_NAME

if TYPE_CHECKING:  # the writer's argument type only: reading a folder needs no evaluator
    from eval.evaluate import EvalResult

SUMMARY_NAME = "summary.json"      # written last: the folder is complete
META_NAME = "eval_meta.json"
PER_VIEW_NAME = "per_view.csv"
RESULT_FILES = (SUMMARY_NAME, PER_VIEW_NAME, META_NAME)


# ---- writing (gspi-eval) ------------------------------------------------------------------------
PACKAGES = ("torch", "numpy", "scikit-image", "kornia", "OpenEXR", "hydra-core")


def environment_info() -> dict:
    """Package versions, Python, machine and the git commit of this checkout (if any)."""
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent, timeout=5).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {"packages": versions, "python": platform.python_version(),
            "machine": platform.machine(), "git_commit": commit}


def clear_result(out_dir: str | Path) -> list[Path]:
    """Removes an earlier evaluation's files from ``out_dir`` BEFORE a new one starts, so a
    killed or failed evaluation never leaves an old summary.json beside a new .hydra/; returns
    the removed paths (the record protocol, docs/RELIABILITY.md)."""
    removed = []
    for name in RESULT_FILES:  # summary.json first: it is the record
        path = Path(out_dir) / name
        if path.is_file():
            path.unlink()
            removed.append(path)
    return removed


def write_result(out_dir: str | Path, result: EvalResult, protocol_dict: dict | None = None) -> None:
    """Write the three result files atomically (a killed run never leaves half a file).

    summary.json holds {channel: {psnr, ssim, lpips}} plus, where the protocol computes them,
    `psnr_h` (relight) and `mae`, `iou` (metallic). per_view.csv adds `psnr_floored` (the
    MSE hit the protocol's floor) and those extra columns.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    extra = [m for m in ("psnr_h", "mae", "iou", "psnr_metal") if any(m in r for r in result.rows)]
    frame = pd.DataFrame(result.rows, columns=["scene", "view", "channel", "env", "psnr", "ssim",
                                               "lpips", "psnr_floored", *extra])
    write_text_atomic(out / PER_VIEW_NAME, frame.to_csv(index=False))
    info = dict(result.info, environment=environment_info())
    if protocol_dict is not None:
        info["protocol_config"] = protocol_dict
    write_text_atomic(out / META_NAME, json.dumps(info, indent=2) + "\n")
    # summary.json LAST: its presence means the other two files are of the same evaluation
    write_text_atomic(out / SUMMARY_NAME, json.dumps(result.summary, indent=2) + "\n")


def format_summary(result: EvalResult) -> str:
    """Plain-text table: channels as rows, PSNR (dB), SSIM (%), LPIPS (%) as columns."""
    p = result.info["protocol"]
    lines = [f"method: {result.info.get('method')}   protocol: {p['name']} v{p['version']} "
             f"#{p.get('hash')}   images: {result.info['num_images']}",
             f"{'channel':<10} {'PSNR':>8} {'SSIM(%)':>8} {'LPIPS(%)':>9} {'floored':>8}  extra"]
    counts = result.info.get("counts", {})
    for channel, m in result.summary.items():
        psnr = "inf" if math.isinf(m["psnr"]) else f"{m['psnr']:.2f}"
        extra = "  ".join(f"{k} {m[k]:.4g}" for k in ("psnr_h", "mae", "iou", "psnr_metal") if k in m)
        floored = counts.get(channel, {}).get("psnr_floored", 0)
        lines.append(f"{channel:<10} {psnr:>8} {100 * m['ssim']:>8.2f} {100 * m['lpips']:>9.2f} "
                     f"{floored:>8}  {extra}".rstrip())
    if result.info.get("missing_scenes"):
        absent = result.info["missing_scenes"]
        lines.append(f"missing scenes: {len(absent)} of the split(s) have no prediction and are not in "
                     f"these means ({', '.join(absent)}); scored: {len(result.info['scenes'])}")
    if result.info.get("missing"):
        lines.append(f"missing predictions: {len(result.info['missing'])} (view, channel) "
                     f"entries, e.g. {result.info['missing'][0]}; see eval_meta.json")
    return "\n".join(lines)


# ---- reading (gspi-table) ----------------------------------------------------------------------
def find_eval_folders(paths: list[str | Path]) -> tuple[list[Path], list[Path]]:
    """(complete, incomplete) gspi-eval folders below each path, recursively.

    Incomplete: summary.json without eval_meta.json, or a Hydra output folder (.hydra/) with
    neither summary.json nor result.json (killed before it wrote anything).
    """
    found, incomplete = set(), set()
    for p in map(Path, paths):
        if not p.exists():
            raise MissingInputError(f"{p}: run folder not found")
        found |= {s.parent for s in p.rglob(SUMMARY_NAME)}
        incomplete |= {h.parent for h in p.rglob(".hydra") if h.is_dir()
                       and not (h.parent / SUMMARY_NAME).is_file()
                       and not (h.parent / RECORD_NAME).is_file()}
    complete = sorted(d for d in found if (d / META_NAME).is_file())
    incomplete |= {d for d in found if not (d / META_NAME).is_file()}
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
