"""End-to-end scores of the shipped Stage II models as their checkpoint cards record them.

Each `checkpoints/stage2_<name>.json` card keeps, per seed, what the shipping rule reads (issue 42,
checkpoints/README.md): the demo's s004 metal IoU and metallic PSNR, and the mean PSNR over the 19
real objects (albedo, roughness, metallic, relight), beside the held-out average. Cards written in
different sessions spell these three ways; :func:`read_card` reads each into one record, so the
shipping-rule and real-object tables (gspi.publish) are generated, never retyped.

A card's ``status`` says what the product does with its file (``STATUSES``), derived from the
configs by :func:`configured_statuses` and written by ``make results`` (:func:`cards_with_status`,
part of gspi.publish' targets), so it never disagrees with them:

- ``default``: the checkpoint gspi-run loads (conf/gspi_run.yaml's ``stage2`` option's ``checkpoint``);
- ``table``: one a product table measures (a ``checkpoints_from`` entry of conf/reproduce/*.yaml);
- ``retired``: every other card; its file stays (tables of earlier sessions were measured with it).

A retired card moves to its study with its file (issue 67); what the shipping rule measured of a
retired candidate stays in the product as a *rule record* (``results/shipping/cpu/<model>/scores.json``,
:func:`rule_record`: the held-out average, s004 and the real objects per seed, in the nested layout),
which :func:`read_card` reads like a card.

A shipped card (``default`` or ``table``) also names the product command that rebuilds its model
from nothing (``rebuild``, :func:`configured_rebuilds`: ``gspi-reproduce model=<name> scale=<s>`` of
a conf/reproduce/model_<name>_<s>.yaml); ``make results`` writes it beside the status.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

REAL_CHANNELS = ("albedo", "roughness", "metallic", "relight")
RULE_CHANNELS = ("albedo", "roughness", "metallic")   # the rule: never behind no decomposition on these
MIN_METAL_IOU = 0.5                                   # the rule: s004's metal found
STATUSES = ("default", "table", "retired")            # a card's ``status``, module docstring
CARD_GLOB = "stage2_*.json"                           # the cards under checkpoints/


@dataclass
class CardScores:
    """One model's recorded end-to-end scores; index i of each list is seed i."""

    model: str                                        # checkpoint stem, e.g. stage2_pool224
    heldout_avg: Optional[float]                      # Table 2's measure, mean of its seeds
    heldout_seeds: int
    s004_iou: list[float] = field(default_factory=list)
    s004_metallic: list[float] = field(default_factory=list)
    real: list[dict] = field(default_factory=list)    # [{channel: psnr}] per seed
    real_baseline: Optional[dict] = None              # no decomposition on the same 19 objects


def _heldout(card: dict) -> tuple[Optional[float], int]:
    held = card.get("heldout_pool_scenes_reconstructed_conditions") or {}
    for key, seeds in (("psnr_mean_of_2_seeds", 2), ("psnr_seed0", 1)):
        if isinstance(held.get(key), dict) and "avg" in held[key]:
            return float(held[key]["avg"]), seeds
    return None, 0


def _demo(demo: dict) -> tuple[list[float], list[float]]:
    if "s004" in demo:                                # sessions 14-18: lists over seeds
        return list(demo["s004"]["metal_iou"]), list(demo["s004"]["metallic_psnr"])
    if "seed0" in demo:                               # session 21 on: {"seed<k>": {"s004": ...}}
        seeds = [demo[k]["s004"] for k in sorted(k for k in demo if k.startswith("seed"))]
    else:                                             # sessions 19-20: "s004_seed<k>"
        seeds = [demo[k] for k in sorted(k for k in demo if k.startswith("s004_seed"))]
    return [s["metal_iou"] for s in seeds], [s["metallic_psnr"] for s in seeds]


def _real(real: dict) -> list[dict]:
    if "seed0" in real:
        return [real[k]["mean_psnr"] for k in sorted(k for k in real if k.startswith("seed"))]
    return [real[k] for k in sorted(k for k in real if k.startswith("mean_psnr_seed"))]


def read_card(path: Path) -> Optional[CardScores]:
    """The card's (or rule record's) scores, or None when it records no end-to-end run (not a rule
    candidate). The model is the record's ``model``, else the card's file stem."""
    card = json.loads(Path(path).read_text())
    demo, real = card.get("demo_end_to_end"), card.get("real_objects_19_small")
    if not demo or not real:
        return None
    avg, seeds = _heldout(card)
    iou, metallic = _demo(demo)
    return CardScores(model=card.get("model") or Path(path).stem, heldout_avg=avg, heldout_seeds=seeds, s004_iou=iou,
                      s004_metallic=metallic, real=_real(real),
                      real_baseline=real.get("no_decomposition_same_data"))


def rule_record(scores: CardScores) -> dict:
    """What the shipping rule reads of a candidate, in the nested layout (:func:`read_card` reads it
    back to ``scores``): the product's record of a retired candidate whose card left with its file."""
    held = {} if scores.heldout_avg is None else {
        "psnr_mean_of_2_seeds" if scores.heldout_seeds == 2 else "psnr_seed0": {"avg": scores.heldout_avg}}
    if scores.heldout_seeds not in (0, 1, 2):
        raise ValueError(f"{scores.model}: {scores.heldout_seeds} held-out seeds, the layouts know 1 or 2")
    demo = {f"seed{i}": {"s004": {"metal_iou": iou, "metallic_psnr": m}}
            for i, (iou, m) in enumerate(zip(scores.s004_iou, scores.s004_metallic))}
    real = {f"seed{i}": {"mean_psnr": dict(means)} for i, means in enumerate(scores.real)}
    if scores.real_baseline is not None:
        real["no_decomposition_same_data"] = dict(scores.real_baseline)
    return {"model": scores.model, "heldout_pool_scenes_reconstructed_conditions": held,
            "demo_end_to_end": demo, "real_objects_19_small": real}


def rule_failures(scores: CardScores) -> list[str]:
    """What keeps seed 0 of a model from passing the shipping rule ([] = it passes)."""
    failed = [] if scores.s004_iou and scores.s004_iou[0] >= MIN_METAL_IOU else ["s004"]
    base = scores.real_baseline or {}
    return failed + [c for c in RULE_CHANNELS if scores.real and c in base and scores.real[0][c] < base[c]]


def default_checkpoint(root: Path) -> str:
    """The stem of the checkpoint gspi-run loads: conf/gspi_run.yaml's ``stage2`` option's ``checkpoint``."""
    import yaml

    conf = Path(root) / "conf"
    defaults = yaml.safe_load((conf / "gspi_run.yaml").read_text())["defaults"]
    option = next((d["stage2"] for d in defaults if isinstance(d, dict) and "stage2" in d), None)
    if option is None:
        raise ValueError(f"{conf / 'gspi_run.yaml'}: its defaults select no stage2 option")
    node = yaml.safe_load((conf / "stage2" / f"{option}.yaml").read_text()) or {}
    if not node.get("checkpoint"):
        raise ValueError(f"{conf / 'stage2' / (option + '.yaml')}: gspi-run's stage2 option names no checkpoint")
    return Path(node["checkpoint"]).stem


def table_checkpoints(root: Path) -> set[str]:
    """The stems of the checkpoints a product table measures (conf/reproduce/*.yaml ``checkpoints_from``)."""
    import yaml

    stems = set()
    for path in sorted((Path(root) / "conf" / "reproduce").glob("*.yaml")):
        named = (yaml.safe_load(path.read_text()) or {}).get("checkpoints_from") or {}
        stems |= {Path(str(ckpt)).stem for ckpt in named.values()}
    return stems


def configured_statuses(root: Path) -> dict[str, str]:
    """{card stem: the status the configs give it} for every card under ``root``/checkpoints."""
    default, tables = default_checkpoint(root), table_checkpoints(root)
    cards = sorted((Path(root) / "checkpoints").glob(CARD_GLOB))
    if default not in {c.stem for c in cards}:
        raise ValueError(f"gspi-run's default checkpoint {default} has no card checkpoints/{default}.json")
    return {c.stem: "default" if c.stem == default else "table" if c.stem in tables else "retired" for c in cards}


def configured_rebuilds(root: Path) -> dict[str, str]:
    """{checkpoint stem: the gspi-reproduce call that rebuilds it} from conf/reproduce/model_*_*.yaml
    (``model: default`` rebuilds gspi-run's default checkpoint)."""
    import yaml

    out = {}
    for path in sorted((Path(root) / "conf" / "reproduce").glob("model_*_*.yaml")):
        model = (yaml.safe_load(path.read_text()) or {}).get("model")
        if model != "default":
            raise ValueError(f"{path}: model {model!r}: only the default model is rebuilt by a reproduce file")
        scale = path.stem.rsplit("_", 1)[1]
        out[default_checkpoint(root)] = f"gspi-reproduce model={model} scale={scale}"
    return out


def read_status(path: Path) -> str:
    """The card's ``status``; ValueError naming the card when it is missing or not one of ``STATUSES``."""
    status = json.loads(Path(path).read_text()).get("status")
    if status not in STATUSES:
        raise ValueError(f"{path}: status {status!r}, expected one of {list(STATUSES)} (make results writes it)")
    return status


def with_status(card: dict, status: str, rebuild: Optional[str] = None) -> dict:
    """The card with ``status`` (and ``rebuild`` when given) set, placed after ``file`` (the rest
    keeps its order)."""
    if status not in STATUSES:
        raise ValueError(f"status {status!r}: expected one of {list(STATUSES)}")
    placed = {"status": status, **({"rebuild": rebuild} if rebuild else {})}
    out = {}
    for key, value in card.items():
        if key not in ("status", "rebuild"):
            out[key] = value
        if key == "file":
            out.update(placed)
    return {**out, **{k: v for k, v in placed.items() if k not in out}}


def cards_with_status(root: Path) -> dict[Path, str]:
    """{card path: its text with the configured status} (the cards' layout: indent 2, newline)."""
    statuses, rebuilds = configured_statuses(root), configured_rebuilds(root)
    out = {}
    for path in sorted((Path(root) / "checkpoints").glob(CARD_GLOB)):
        card = json.loads(path.read_text())
        out[path] = json.dumps(with_status(card, statuses[path.stem], rebuilds.get(path.stem)), indent=2) + "\n"
    return out
