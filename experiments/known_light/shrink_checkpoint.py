"""A light-aware Stage II checkpoint whose x0_readout head corrects the read-out's roughness by a
fraction ``scale`` of what it learned: ``x0 = read-out + scale * head`` on that channel (finding 35).

Finding 34's prior pulls each point's roughness towards its training pool's mean: the glossy and matte
members of the controlled pairs come out 0.16-0.34 apart where the read-out it is given has them
0.55-0.66 apart. The head's last layer is linear, so scaling its roughness row (weight and bias)
scales that channel's correction exactly: ``scale`` 0 is the read-out, 1 the prior. The curve over
``scale`` says what keeping more of the read-out's spread costs on Table 2's measure, with no
retraining. Writes an EMA-only copy; its config records the scale.

    python -m experiments.known_light.shrink_checkpoint SRC DST --scale 0.5
"""
from __future__ import annotations

import argparse
from pathlib import Path

from gspi.stage2.checkpoint import CheckpointError, ema_only, read_checkpoint, save_atomic
from gspi.stage2.model import METALLIC

ROUGHNESS = METALLIC - 1  # the diffused features: albedo RGB, roughness, metallic


def with_correction_scale(ckpt: dict, scale: float, path: str | Path = "<checkpoint>",
                          channel: int = ROUGHNESS) -> dict:
    """The EMA-only content of ``ckpt`` with the x0_readout head's ``channel`` correction times ``scale``."""
    if ckpt["rcw_config"].get("prediction") != "x0_readout":
        raise CheckpointError(f"{path}: the scale applies to an x0_readout head's correction; this model's "
                              f"head predicts {ckpt['rcw_config'].get('prediction')!r}")
    if not 0.0 <= scale <= 1.0:
        raise ValueError(f"--scale {scale}: a fraction of the learned correction, between 0 and 1")
    out = ema_only(ckpt)
    ema = dict(out["ema"])
    for name in ("out.weight", "out.bias"):
        tensor = ema[name].clone()
        tensor[channel] *= scale
        ema[name] = tensor
    out["ema"] = ema
    out["config"] = {**out["config"], "readout_correction_scale": {"channel": channel, "scale": scale}}
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    parser.add_argument("--scale", type=float, required=True, help="fraction of the roughness correction kept")
    args = parser.parse_args(argv)
    save_atomic(with_correction_scale(read_checkpoint(args.src), args.scale, args.src), args.dst)
    print(f"{args.dst}: {args.src} with its roughness correction times {args.scale:g}")


if __name__ == "__main__":
    main()
