"""The light read-out's correction, scaled after training (issue 66; the known-light study's finding 35).

An ``x0_readout`` head (gspi/stage2/model.py) predicts ``x0 = read-out + correction``. A prior trained
so pulls each point towards its training pool's mean, and on roughness that pull costs the contrast
the read-out sees: the controlled glossy/matte pairs came out 0.16-0.34 apart where the read-out had
them 0.55-0.66 apart. Keeping a fraction of the learned correction, ``x0 = read-out + scale *
correction`` per channel, is exact on the trained weights: the head's last layer is linear, so its
rows (weight and bias) of a channel are scaled. Scale 0 is the read-out, 1 the prior as trained.
The EMA-only result records the scales in its config (``readout_correction_scale``).
"""
from __future__ import annotations

from pathlib import Path

from gspi.stage2.checkpoint import CheckpointError, ema_only
from gspi.stage2.model import METALLIC

CHANNELS = {"albedo": (0, 1, 2), "roughness": (METALLIC - 1,), "metallic": (METALLIC,)}  # diffused features
HEAD = ("out.weight", "out.bias")  # the head's last (linear) layer in the EMA state


def scale_readout_correction(ckpt: dict, scales: dict[str, float], path: str | Path = "<checkpoint>") -> dict:
    """The EMA-only content of ``ckpt`` whose x0_readout head keeps ``scales[channel]`` of its
    correction of each named channel (``albedo``, ``roughness``, ``metallic``), the rest as trained."""
    if ckpt["rcw_config"].get("prediction") != "x0_readout":
        raise CheckpointError(f"{path}: a correction scale applies to an x0_readout head's correction; this "
                              f"model's head predicts {ckpt['rcw_config'].get('prediction')!r}")
    for channel, scale in scales.items():
        if channel not in CHANNELS:
            raise ValueError(f"readout correction scale: unknown channel {channel!r} (one of {sorted(CHANNELS)})")
        if not 0.0 <= float(scale) <= 1.0:
            raise ValueError(f"readout correction scale of {channel}: {scale} is not a fraction between 0 and 1")
    out = ema_only(ckpt)
    ema = dict(out["ema"])
    for name in HEAD:
        tensor = ema[name].clone()
        for channel, scale in scales.items():
            tensor[list(CHANNELS[channel])] *= float(scale)
        ema[name] = tensor
    before = dict(out["config"].get("readout_correction_scale", {}))
    applied = {c: before.get(c, 1.0) * float(s) for c, s in scales.items()}
    out["ema"] = ema
    out["config"] = {**out["config"], "readout_correction_scale": {**before, **applied}}
    return out
