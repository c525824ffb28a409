"""A light-aware Stage II checkpoint whose x0_readout head corrects the read-out's roughness by a
fraction ``scale`` of what it learned: ``x0 = read-out + scale * correction`` on that channel (finding 35;
the product's ``gspi.stage2.readout_correction``).

Finding 34's prior pulls each point's roughness towards its training pool's mean: the glossy and matte
members of the controlled pairs come out 0.16-0.34 apart where the read-out it is given has them
0.55-0.66 apart. The curve over ``scale`` (0 the read-out, 1 the prior) says what keeping more of the
read-out's spread costs on Table 2's measure, with no retraining.

    python -m experiments.known_light.shrink_checkpoint SRC DST --scale 0.5 [--metallic 0]
"""
from __future__ import annotations

import argparse
from pathlib import Path

from gspi.stage2.checkpoint import read_checkpoint, save_atomic
from gspi.stage2.readout_correction import scale_readout_correction


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path)
    parser.add_argument("dst", type=Path)
    parser.add_argument("--scale", type=float, required=True, help="fraction of the roughness correction kept")
    parser.add_argument("--metallic", type=float, default=1.0, help="fraction of the metallic correction kept")
    args = parser.parse_args(argv)
    scales = {"roughness": args.scale, **({"metallic": args.metallic} if args.metallic != 1.0 else {})}
    save_atomic(scale_readout_correction(read_checkpoint(args.src), scales, args.src), args.dst)
    print(f"{args.dst}: {args.src} with its correction times {scales}")


if __name__ == "__main__":
    main()
