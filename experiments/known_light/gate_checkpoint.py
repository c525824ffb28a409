"""A light-aware Stage II checkpoint with the read-out's metal gate switched on after training
(``stage2.diffusion.readout_metal_gate``, finding 28): what the gate alone does to a prior trained
without it, measured before any retraining with it. Writes an EMA-only copy; the weights are
untouched, only the model config (and the stored ``stage2`` config, which Table 2's measure reads)
gains the gate.

    python -m experiments.known_light.gate_checkpoint SRC DST
"""
from __future__ import annotations

import argparse
from pathlib import Path

from gspi.stage2.checkpoint import CheckpointError, ema_only, read_checkpoint, save_atomic


def with_metal_gate(ckpt: dict, path: str | Path = "<checkpoint>") -> dict:
    """The EMA-only content of ``ckpt`` with ``readout_metal_gate`` on (an x0_readout model only)."""
    if ckpt["rcw_config"].get("prediction") != "x0_readout":
        raise CheckpointError(f"{path}: the metal gate corrects an x0_readout head; this model's head predicts "
                              f"{ckpt['rcw_config'].get('prediction')!r}")
    out = ema_only(ckpt)
    out["rcw_config"] = {**out["rcw_config"], "readout_metal_gate": True}
    stage2 = dict(out["config"]["stage2"])
    stage2["diffusion"] = {**stage2["diffusion"], "readout_metal_gate": True}
    out["config"] = {**out["config"], "stage2": stage2, "metal_gate_added_after_training": True}
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    args = parser.parse_args(argv)
    save_atomic(with_metal_gate(read_checkpoint(args.src), args.src), args.dst)
    print(f"{args.dst}: {args.src} with stage2.diffusion.readout_metal_gate=true")


if __name__ == "__main__":
    main()
