"""Table 2's measure as a protocol: the knobs that define it (``conf/points_measure/``), checked
once, and its identity, a short hash computed by Table 1's hasher (``eval.protocol_id.protocol_hash``)
over those knobs, recorded in every ``scores.json`` of format "gspi-points-eval" as
``measure_protocol: {name, hash}``.

Two scores are one measure only when every knob is equal: ``points_measure.num_steps=2`` keeps the
name ``table2`` and changes the hash. The name labels; only the knobs are hashed, so a scores file
written before the hash was recorded (its knobs are top-level keys, absent = the default below)
hashes as the same measure taken today (``recorded_measure_hash``).
"""
from __future__ import annotations

from typing import Any, Mapping

from eval.common.errors import StatedError
from eval.protocol_id import protocol_hash

# every knob of the measure and the value a scores.json means when it does not record it
# (python -m gspi.stage2.evaluate_points' defaults, which wrote these keys only when not default)
MEASURE_DEFAULTS: dict[str, Any] = {
    "split": "test",          # the scenes scored
    "num_steps": 50,          # DDIM steps
    "max_points": None,       # per scene: a seeded subset of this many points + 1-NN fill; None = every point
    "seed": 0,                # the subset's and the diffusion noise's seed
    "num_samples": 1,         # DDIM samples averaged per point
    "guidance_scale": 1.0,    # classifier-free guidance (1 = off)
    "patch_points": None,     # k-NN patches of this many points; None = the whole cloud
    "patch_coverage": 2.0,    # patches per point on average
    "told_light": "estimated",  # the light a light-aware model is told: one of TOLD_LIGHTS
}
_TYPES = {"split": str, "num_steps": int, "max_points": int, "seed": int, "num_samples": int,
          "guidance_scale": float, "patch_points": int, "patch_coverage": float, "told_light": str}
# What a model that reads the light (stage2.data.light_readout) is told in the measure: the light
# estimated among its candidates (as a run), or, deliberately wrong (issue 66's guard rail), that
# estimate turned 90 degrees about +z, or another of the candidates at the estimate's turn and gain.
TOLD_LIGHTS = ("estimated", "turned90", "other")
# knobs added after scores were committed: hashed only when set off their default, so that every
# earlier measure keeps its hash
ADDED_KNOBS = ("told_light",)


class MeasureError(StatedError, ValueError):
    """A points_measure config with an unknown key or a value of the wrong kind."""


def measure_knobs(measure: Mapping[str, Any]) -> dict[str, Any]:
    """The checked knobs of a measure (a ``points_measure`` node or a dict; ``name`` dropped),
    every knob present (absent = ``MEASURE_DEFAULTS``), ints and floats of one spelling so that
    equal measures hash equal."""
    unknown = sorted(set(measure) - set(MEASURE_DEFAULTS) - {"name"})
    if unknown:
        raise MeasureError(f"points_measure: unknown key(s) {', '.join(unknown)} "
                           f"(known: name, {', '.join(MEASURE_DEFAULTS)})")
    knobs = {}
    for key, default in MEASURE_DEFAULTS.items():
        value = measure.get(key, default)
        if value is not None:
            try:
                value = _TYPES[key](value)
            except (TypeError, ValueError):
                raise MeasureError(f"points_measure.{key}={value!r}: not a {_TYPES[key].__name__}") from None
        elif default is not None:
            raise MeasureError(f"points_measure.{key}: null (only max_points and patch_points may be)")
        knobs[key] = value
    if knobs["told_light"] not in TOLD_LIGHTS:
        raise MeasureError(f"points_measure.told_light={knobs['told_light']!r}: one of {', '.join(TOLD_LIGHTS)}")
    return knobs


def measure_hash(measure: Mapping[str, Any]) -> str:
    """The measure's identity: ``protocol_hash`` (Table 1's) of its checked knobs (an
    ``ADDED_KNOBS`` knob only when off its default)."""
    knobs = measure_knobs(measure)
    return protocol_hash({k: v for k, v in knobs.items() if k not in ADDED_KNOBS or v != MEASURE_DEFAULTS[k]})


def measure_record(name: str | None, measure: Mapping[str, Any]) -> dict[str, Any]:
    """``scores.json``'s ``measure_protocol``: {name (the conf/points_measure option, None for a
    measure set by flags), hash}."""
    return {"name": name, "hash": measure_hash(measure)}


def recorded_measure(scores: Mapping[str, Any]) -> dict[str, Any]:
    """The knobs a scores.json was measured with (its top-level keys; absent = default)."""
    return measure_knobs({k: scores[k] for k in MEASURE_DEFAULTS if k in scores})


def recorded_measure_hash(scores: Mapping[str, Any]) -> str:
    """The measure hash of a scores.json: the one it records, else computed from its knobs."""
    return (scores.get("measure_protocol") or {}).get("hash") or measure_hash(recorded_measure(scores))
