"""Protocol identity: a hash of the whole resolved protocol, the keys two protocols differ in,
and the one-line description every table footer prints (docs/PROTOCOL.md, "Identity").

Two evaluations are comparable only when every field of their protocol is equal: an override
such as `eval.relight.tonemap=clamp` keeps the protocol's name and version but changes its hash.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math

from eval.common.errors import StatedError

HASH_CHARS = 12


def protocol_dict(protocol) -> dict:
    """The resolved protocol as plain JSON-able data (DictConfig, dataclass or dict)."""
    if isinstance(protocol, dict):
        return protocol
    if dataclasses.is_dataclass(protocol):
        return dataclasses.asdict(protocol)
    from omegaconf import OmegaConf

    return OmegaConf.to_container(protocol, resolve=True)


# spellings with one meaning; `lattice` names the views of a scene's `train` folder: the 32
# lattice views the method reconstructs from (docs/PROTOCOL.md, "Views")
ALIASES = {"albedo_alignment": {"per_channel": "lstsq"}, "split": {"lattice": "train"}}
SPLIT_LABELS = {"train": "lattice views", "val": "validation views"}  # footer words; test: none


def scored_split(protocol) -> str:
    """The view folder a protocol scores (`eval.split` with `lattice` resolved to `train`)."""
    split = protocol["split"] if isinstance(protocol, dict) else protocol.split
    return ALIASES["split"].get(split, split)


# Keys added after a protocol was in use, whose default IS the earlier behaviour: at that
# default they are dropped before hashing, so an evaluation recorded before the key existed
# and one recorded after hash alike (and tables may mix them); any other value is hashed.
# Dotted keys name nested fields. (Issue 28 added the field's conventions as options.)
LATER_KEYS = {"unpremultiply": False, "alignment_space": "linear", "alignment_pixels": "mask",
              "alignment_sampled_views": None, "albedo_clamp": True, "mask_prediction": True,
              "psnr.channel_mean": False, "psnr.map_pooling": "view", "psnr.albedo_space": None,
              "ssim.albedo_space": None, "lpips.albedo_space": None, "relight.clamp_albedo": True,
              "outside_brdf": "include", "relight.reference": "shaded"}


def _drop_neutral(tree: dict, dotted: str, neutral) -> None:
    head, _, rest = dotted.partition(".")
    if rest:
        if isinstance(tree.get(head), dict):
            tree[head] = dict(tree[head])
            _drop_neutral(tree[head], rest, neutral)
    elif head in tree and type(tree[head]) is type(neutral) and tree[head] == neutral:
        del tree[head]


def canonical(protocol: dict) -> dict:
    """The protocol with aliases resolved and later keys at their neutral default dropped, so
    equal conventions hash equal."""
    out = dict(protocol)
    for key, names in ALIASES.items():
        if out.get(key) in names:
            out[key] = names[out[key]]
    for key, neutral in LATER_KEYS.items():
        _drop_neutral(out, key, neutral)
    return out


def protocol_hash(protocol: dict) -> str:
    """First 12 hex digits of the SHA-256 of the canonical JSON of the whole protocol."""
    text = json.dumps(canonical(protocol), sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:HASH_CHARS]


def flatten(tree: dict, prefix: str = "") -> dict:
    """{"a": {"b": 1}} -> {"a.b": 1}."""
    flat = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            flat.update(flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def protocol_diff(a: dict, b: dict) -> list[str]:
    """Dotted keys whose values differ, as "key: a_value != b_value" (missing: <absent>)."""
    fa, fb = flatten(canonical(a or {})), flatten(canonical(b or {}))
    return [f"{k}: {fa.get(k, '<absent>')!r} != {fb.get(k, '<absent>')!r}"
            for k in sorted(set(fa) | set(fb)) if fa.get(k, "<absent>") != fb.get(k, "<absent>")]


class ProtocolMixError(StatedError, ValueError):
    """Runs to be tabulated together were evaluated under different protocols."""


def check_one_protocol(runs: dict[str, dict | None]) -> str:
    """Refuse runs evaluated under different protocols; return the common hash.

    Args:
        runs: {run folder: resolved protocol dict (see `recorded_protocol`)}.
    Raises:
        ProtocolMixError (a ValueError) naming the runs of each hash and the keys that differ.
    """
    groups: dict[str, list[str]] = {}
    for run, proto in runs.items():
        groups.setdefault(protocol_hash(proto), []).append(run)
    if len(groups) > 1:
        (h0, r0), *others = groups.items()
        parts = [f"protocol {h0}: {', '.join(r0)}"]
        for h, rs in others:
            diff = protocol_diff(runs[r0[0]], runs[rs[0]])
            parts.append(f"protocol {h}: {', '.join(rs)} (differs from {h0} in "
                         f"{'; '.join(diff)})")
        raise ProtocolMixError("tables never mix protocols; runs were evaluated under "
                         f"{len(groups)} different protocols:\n  " + "\n  ".join(parts))
    return next(iter(groups)) if groups else ""


def recorded_protocol(meta: dict) -> dict:
    """The protocol an eval_meta.json records: its full `protocol_config`, else (folders
    written before protocol v1 recorded it) just {"name", "version"}, which then differs
    from any full protocol in every other key."""
    config = meta.get("protocol_config")
    if isinstance(config, dict) and config:
        return config
    p = meta.get("protocol") or {}
    return {"name": p.get("name"), "version": p.get("version")}


def describe_protocol(p: dict) -> str:
    """Every knob a reader needs to compare numbers, in one line."""
    if set(p) <= {"name", "version"}:
        return f"{p.get('name')} v{p.get('version')} (no protocol_config recorded: knobs unknown)"
    r, lp, ps, ss = p.get("relight", {}), p.get("lpips", {}), p.get("psnr", {}), p.get("ssim", {})
    floor = float(ps.get("mse_floor", 0.0))
    floor_text = (f"MSE floor {floor:.3g} (cap {10 * math.log10(1 / floor):.1f} dB)" if floor > 0
                  else "no MSE floor (recorded before the floor: an exact image scored +inf)")
    tone = r.get("tonemap")
    tone_text = (f"linear clipped to [0, {r.get('hdr_max')}]" if tone == "none" else
                 f"{tone}{'+sRGB' if r.get('srgb') else ''}, exposure {r.get('exposure_stops')} stops")
    split = ALIASES["split"].get(p.get("split"), p.get("split"))
    label = f" ({SPLIT_LABELS[split]})" if split in SPLIT_LABELS else ""
    return (f"{p.get('name')} v{p.get('version')} #{protocol_hash(p)}: split {split}{label}; "
            f"albedo alignment {p.get('albedo_alignment')} (scope {p.get('alignment_scope')}), "
            f"scored in {p.get('albedo_space', 'srgb')}; GT mask eroded "
            f"{p.get('mask_erosion_px', 0)} px"
            f"{', outside-BRDF pixels excluded' if p.get('outside_brdf') == 'exclude' else ''}"
            f"{'; maps un-premultiplied by the method alpha.png' if p.get('unpremultiply') else ''}"
            f"; PSNR over {ps.get('region', 'mask')}, {floor_text}"
            f"{', grey floor' if ps.get('grey_floor') else ''}; "
            f"SSIM window {ss.get('window', 11)} {ss.get('padding', 'valid')} over "
            f"{ss.get('region', 'mask')}; LPIPS "
            f"{lp.get('net')} v{lp.get('version')} {lp.get('mode')}, inputs "
            f"{'[-1,1]' if lp.get('normalize', True) else '[0,1]'}"
            f"{', sRGB-encoded first' if lp.get('encode_srgb') else ''}; background "
            f"{p.get('background')}; relight tone map {tone_text}, scale fit "
            f"{r.get('scale_fit', 'none')}{', PSNR-H' if r.get('psnr_hdr') else ''}"
            f"{', GT = stored relit images' if r.get('reference') == 'stored' else ''}, fills "
            f"roughness {r.get('fill_roughness')} metallic {r.get('fill_metallic')}, envs "
            f"{r.get('envs') or 'each scene held-out'}")


def describe_counts(counts: dict) -> str:
    """"albedo 24 (0 at PSNR floor), ..." from eval_meta.json counts (summed over runs)."""
    if not counts:
        return "Image counts not recorded"
    parts = []
    for channel, c in counts.items():
        extra = f", {c['mae_iou']} with metal MAE/IoU" if c.get("mae_iou") else ""
        parts.append(f"{channel} {c['images']} ({c['psnr_floored']} at PSNR floor{extra})")
    return "Images scored: " + ", ".join(parts)


def sum_counts(all_counts: list[dict]) -> dict:
    """Add {channel: {key: n}} dicts."""
    total: dict = {}
    for counts in all_counts:
        for channel, c in (counts or {}).items():
            t = total.setdefault(channel, {})
            for key, n in c.items():
                t[key] = t.get(key, 0) + int(n)
    return total
