"""Score a prediction folder against a ground-truth dataset under a protocol.

`evaluate(gt_root, pred_root, protocol)` walks every scene present in the prediction folder,
every view of the protocol's split and every channel, and returns per-view rows plus the
summary (mean over images) and run information. Nothing here knows how predictions were made.

Device (``device=``, gspi-eval's ``device=auto|cpu|cuda``): files are read on the CPU and their
tensors moved to the device, where the environments are prefiltered and the relighting, SSIM
and LPIPS run; scores come back as Python floats. On the CPU (the default) this is the code
path of before, bit for bit.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from eval.checksums import ALGORITHM as CHECKSUM_ALGORITHM
from eval.checksums import combined, scene_checksums
from eval.common.layout import (MATERIAL_CHANNELS, LayoutError, Scene, no_images_message, read_meta,
                         read_scene, read_splits)
from eval.protocol_id import protocol_dict, protocol_hash, scored_split
from eval.scored_view import CPU, EnvironmentCache, scene_scored_views
from eval.scoring import METRIC_NAMES as METRICS
from eval.scoring import has_metal, metal_scores, pooled_psnr, score_map, score_relit_pair

log = logging.getLogger(__name__)
EXTRA_METRICS = ("psnr_h", "mae", "iou", "psnr_metal")  # present only where the protocol computes them


@dataclass
class EvalResult:
    rows: list[dict]                 # one per (scene, view, channel, env)
    summary: dict                    # {channel: {metric: mean}} for channels the method has
    info: dict = field(default_factory=dict)  # method, protocol, runtimes, missing views, ...


def find_scenes(gt_root: Path) -> dict[str, Path]:
    """Scene name -> folder, for a dataset folder or a single scene folder."""
    gt_root = Path(gt_root)
    if (gt_root / "scene.json").is_file():
        return {read_scene(gt_root).name: gt_root}
    scenes = {p.parent.name: p.parent for p in sorted(gt_root.glob("*/scene.json"))}
    if not scenes:
        raise LayoutError(f"{gt_root}: no scene.json here or in any subfolder")
    return scenes


def scenes_in_prediction(pred_root: Path, gt_scenes: dict[str, Path]) -> list[str]:
    """Names of ground-truth scenes that have a folder in the prediction."""
    pred_root = Path(pred_root)
    if not pred_root.is_dir():
        raise LayoutError(f"{pred_root}: prediction folder not found")
    if (pred_root / "scene.json").is_file() and pred_root.name in gt_scenes:
        return [pred_root.name]  # a single scene folder given as the prediction
    names = [p.name for p in sorted(pred_root.iterdir()) if p.is_dir() and p.name in gt_scenes]
    unknown = [p.name for p in pred_root.iterdir()
               if p.is_dir() and not p.name.startswith(".") and p.name not in gt_scenes]
    if unknown:
        log.warning("%s: folders that are not ground-truth scenes are ignored: %s",
                    pred_root, ", ".join(sorted(unknown)))
    if not names:
        raise LayoutError(f"{pred_root}: no scene of the ground truth is present in the "
                          f"prediction (ground-truth scenes: {', '.join(sorted(gt_scenes))})")
    return names


def expected_scenes(gt_root: Path, present: list[str], gt_scenes: dict[str, Path]) -> list[str]:
    """Ground-truth scenes a complete prediction would hold: those of every dataset split
    (``splits.json``) that one of the ``present`` scenes belongs to; every ground-truth scene
    when the dataset has no ``splits.json``; just the scene for a single scene folder."""
    gt_root = Path(gt_root)
    if (gt_root / "scene.json").is_file():
        return list(present)
    if not (gt_root / "splits.json").is_file():
        return sorted(gt_scenes)
    splits = read_splits(gt_root)
    return sorted({n for names in splits.values() if set(names) & set(present) for n in names} & set(gt_scenes))


def _named(where: Path, score, *args) -> dict:
    """``score(*args)``; a refusal of the metrics (e.g. a mask too close to the border for the
    SSIM window) is re-raised naming ``where`` (the ground-truth view folder's mask)."""
    try:
        return score(*args)
    except LayoutError:
        raise
    except ValueError as exc:
        raise LayoutError(f"{where / 'mask.png'}: {exc}") from exc


def evaluate_scene(scene: Scene, pred_scene: Path, protocol, net, envs: EnvironmentCache
                   ) -> tuple[list[dict], list[dict]]:
    """Rows for one scene and the list of missing (view, channel) entries; the tensors live
    on ``envs.device``. The images scored are ``eval.scored_view``'s."""
    views, missing = scene_scored_views(scene, pred_scene, protocol, envs)
    if protocol.fail_on_missing_view and missing:
        raise LayoutError(f"{pred_scene}: missing prediction files: {missing[:5]} ...")
    with_metal = [sv for sv in views if "metallic" in sv.gt]
    metal = protocol.metallic.extra_metrics and bool(with_metal) and has_metal(
        [sv.gt["metallic"] for sv in with_metal], [sv.mask for sv in with_metal], float(protocol.metallic.threshold))
    split = scored_split(protocol)
    rows = []
    for sv in views:
        where = scene.view_dir(split, sv.view)
        for c in MATERIAL_CHANNELS:
            if c in protocol.channels and c in sv.pred and c in sv.gt:  # a channel the GT lacks is absent
                row = {"scene": scene.name, "view": sv.view, "channel": c, "env": "",
                       **_named(where, score_map, c, sv.pred[c], sv.gt[c], sv.mask, protocol, net)}
                if c == "metallic" and metal:
                    row.update(metal_scores(sv.pred[c], sv.gt[c], sv.mask, protocol.metallic))
                rows.append(row)
        for env_name, pair in sv.relit.items():
            rows.append({"scene": scene.name, "view": sv.view, "channel": "relight", "env": env_name,
                         **_named(where, score_relit_pair, pair, sv.mask, protocol, net)})
    if protocol.psnr.map_pooling == "scene":
        pool_map_psnr(rows, views, protocol)
    for row in rows:  # metallic PSNR again, over the scenes with metal only (a method that
        if row["channel"] == "metallic" and "mae" in row:  # predicts 0 everywhere scores low here)
            row["psnr_metal"] = row["psnr"]
    divided = {sv.view for sv in views if sv.unpremultiplied}
    for row in rows:
        if row["view"] in divided:
            row["unpremultiplied"] = True
    return rows, missing


def absent_channels(scene: Scene, protocol) -> list[str]:
    """Channels of ``eval.channels`` that no view of the scored split has ground truth for
    (scene.json ``gt_channels``): reported as absent, never scored as 0."""
    views = scene.split_views(scored_split(protocol))
    have = {c for v in views for c in scene.view_gt_channels(v)}
    return [c for c in protocol.channels if c not in have]


def pool_map_psnr(rows: list[dict], views: list, protocol) -> None:
    """``psnr.map_pooling: scene``: every material-map row of the scene gets the PSNR of one MSE
    pooled over the scene's scored views (its own per-view PSNR kept as ``psnr_view``)."""
    for c in MATERIAL_CHANNELS:
        mine = [r for r in rows if r["channel"] == c]
        if not mine:
            continue
        have = [sv for sv in views if c in sv.pred and c in sv.gt]
        psnr, floored = pooled_psnr(c, [sv.pred[c] for sv in have], [sv.gt[c] for sv in have],
                                    [sv.mask for sv in have], protocol)
        for r in mine:
            r["psnr_view"], r["psnr"], r["psnr_floored"] = r["psnr"], psnr, floored


def summarise(rows: list[dict]) -> dict:
    """{channel: {metric: mean over images}} in the fixed channel order; absent if no row.
    Extra metrics (psnr_h, mae, iou) are means over the rows that have them."""
    summary = {}
    for channel in (*MATERIAL_CHANNELS, "relight"):
        sel = [r for r in rows if r["channel"] == channel]
        if sel:
            summary[channel] = {m: float(np.mean([r[m] for r in sel])) for m in METRICS}
            for m in EXTRA_METRICS:
                vals = [r[m] for r in sel if r.get(m) is not None]
                if vals:
                    summary[channel][m] = float(np.mean(vals))
    return summary


def image_counts(rows: list[dict]) -> dict:
    """{channel: {images, psnr_floored, mae_iou}}: how many images each mean averages, how
    many hit the PSNR floor, how many carry metallic MAE/IoU."""
    counts = {}
    for channel in (*MATERIAL_CHANNELS, "relight"):
        sel = [r for r in rows if r["channel"] == channel]
        if sel:
            counts[channel] = {"images": len(sel),
                               "psnr_floored": sum(bool(r.get("psnr_floored")) for r in sel)}
            if any(r.get("mae") is not None for r in sel):
                counts[channel]["mae_iou"] = sum(r.get("mae") is not None for r in sel)
    return counts


def _mean_runtime(metas: list[dict], key: str) -> float | None:
    vals = [m.get("runtime_s", {}).get(key) for m in metas]
    vals = [v for v in vals if v is not None]
    return float(np.mean(vals)) / 60.0 if vals else None


def peak_memory_mb(metas: list[dict]) -> dict:
    """{"rss"[, "cuda"]}: the largest peak of any stage of any scene (meta.json ``stages``,
    gspi/stage_clock.py), in MB; {} when no prediction recorded its stages (an imported method)."""
    out = {}
    for key, name in (("peak_rss_mb", "rss"), ("peak_cuda_mb", "cuda")):
        vals = [s[key] for m in metas for s in (m.get("stages") or {}).values()
                if isinstance(s, dict) and s.get(key) is not None]
        if vals:
            out[name] = float(max(vals))
    return out


def evaluate(gt_root: str | Path, pred_root: str | Path, protocol, *, net=None,
             method: str | None = None, progress: bool = False,
             device: torch.device | str = CPU) -> EvalResult:
    """Evaluate every scene present in `pred_root` (docs/PROTOCOL.md).

    Args:
        net: the LPIPS network (loaded on ``device`` when None; one passed in runs where it is).
        device: where the scoring computes (module docstring); resolved by the caller
            (eval.common.device.resolve_device).
    """
    device = torch.device(device)
    gt_scenes = find_scenes(Path(gt_root))
    names = scenes_in_prediction(Path(pred_root), gt_scenes)
    if net is None and "lpips" in METRICS:
        from eval.lpips.net import load_lpips
        net = load_lpips(net=protocol.lpips.net, version=str(protocol.lpips.version), device=device)
    if getattr(net, "net_name", protocol.lpips.net) != protocol.lpips.net:
        raise ValueError(f"the LPIPS network passed in is {net.net_name!r} but the protocol "
                         f"asks for eval.lpips.net={protocol.lpips.net!r}")
    envs, rows, missing, metas, absent, sums = EnvironmentCache(device), [], [], [], {}, {}
    iterator = names
    if progress:
        from tqdm import tqdm
        iterator = tqdm(names, desc="eval", unit="scene")
    for name in iterator:
        pred_scene = Path(pred_root) if Path(pred_root).name == name and \
            (Path(pred_root) / "scene.json").is_file() else Path(pred_root) / name
        scene = read_scene(gt_scenes[name])
        for c in absent_channels(scene, protocol):
            absent.setdefault(c, []).append(name)
        scene_rows, scene_missing = evaluate_scene(scene, pred_scene, protocol, net, envs)
        rows += scene_rows
        missing += scene_missing
        metas.append(read_meta(pred_scene))
        sums[name] = scene_checksums(gt_scenes[name], pred_scene, scored_split(protocol))
    if absent:
        log.info("channels the ground truth does not provide, not scored (absent, not 0): %s",
                 "; ".join(f"{c} ({', '.join(n)})" for c, n in absent.items()))
    if not rows and set(protocol.channels) <= set(absent) and all(len(n) == len(names) for n in absent.values()):
        raise LayoutError(f"{gt_scenes[names[0]] / 'scene.json'}: the ground truth provides none of "
                          f"eval.channels={list(protocol.channels)} (gt_channels: "
                          f"{list(read_scene(gt_scenes[names[0]]).gt_channels)}): nothing to score")
    if not rows:  # "images: 0" with exit 0 read as "not modelled" (docs/RELIABILITY.md)
        raise LayoutError(no_images_message(Path(pred_root), read_scene(gt_scenes[names[0]]),
                                            scored_split(protocol), list(protocol.channels)))
    methods = sorted({m["method"] for m in metas if "method" in m})
    missing_scenes = [n for n in expected_scenes(Path(gt_root), names, gt_scenes) if n not in names]
    if missing_scenes:  # a method that skips a hard scene must not look better unnoticed
        log.warning("%s: %d ground-truth scene(s) of the evaluated split(s) have no prediction and "
                    "are not scored: %s", pred_root, len(missing_scenes), ", ".join(missing_scenes))
    info = {
        "method": method or (methods[0] if len(methods) == 1 else Path(pred_root).name),
        "protocol": {"name": protocol.name, "version": int(protocol.version),
                     "hash": protocol_hash(protocol_dict(protocol))},
        "checksums": {"algorithm": CHECKSUM_ALGORITHM, **combined(sums), "per_scene": sums},
        "protocol_config": protocol_dict(protocol),
        "data": str(Path(gt_root).resolve()), "device": str(device), "counts": image_counts(rows),
        "scenes": names, "missing_scenes": missing_scenes, "num_images": len(rows), "missing": missing,
        "absent_gt": absent,
        "runtime_min": {"material": _mean_runtime(metas, "material"),
                        "end_to_end": _mean_runtime(metas, "end_to_end"),
                        **({"geometry": _mean_runtime(metas, "geometry")}
                           if any("geometry" in m.get("runtime_s", {}) for m in metas) else {})},
        "peak_memory_mb": peak_memory_mb(metas),
        "per_scene": {n: summarise([r for r in rows if r["scene"] == n]) for n in names},
    }
    if getattr(protocol, "unpremultiply", False):  # how many views carried an alpha.png and were divided by it
        info["unpremultiplied_views"] = len({(r["scene"], r["view"]) for r in rows if r.get("unpremultiplied")})
    floored = sum(c["psnr_floored"] for c in info["counts"].values())
    if floored:
        info["note"] = (f"{floored} image(s) hit the PSNR floor (MSE <= {protocol.psnr.mse_floor:g}, "
                        f"PSNR {10 * math.log10(1 / float(protocol.psnr.mse_floor)):.2f} dB)")
    return EvalResult(rows=rows, summary=summarise(rows), info=info)
