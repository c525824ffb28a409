"""Issue 42, session 18: a training view whose train split holds each pool scene twice, once with
the conditions of its Stage 0 reconstruction (as the paper trains) and once with the exact renders.

Why: on Table 2's held-out measure (reconstructed conditions) the model trained on exact renders
of the one-class pool was the best (`stage2_pool_trunc_snr`, 16.15 dB) yet lost s004's metal end
to end, and the models trained on reconstructions find metal end to end but score lower. Whether
a model that sees both keeps both is the question; this only builds the data view (symlinks and a
`splits.json`), so a training reads it with no code change:

    python experiments/training_pools/mix_conditions.py data/matte_pool/rpool64 \
        data/matte_pool/pool64 data/matte_pool/mix64
    gspi-train data=data/matte_pool/mix64 out=... stage2=cpu_parts_pool seed=0

Each batch item picks its scene uniformly, so half the items see each kind of condition. The
exact scenes are named ``exact_<scene>`` (the prior-feature cache is keyed by scene name).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from eval.common.layout import read_splits
from gspi.data.pool.split import link_scene


def mix_view(recon: Path, exact: Path, out: Path) -> dict[str, list[str]]:
    """Writes ``out`` (symlinks + splits.json) and returns its splits."""
    names = read_splits(recon).get("train", [])
    exact_names = set(read_splits(exact).get("train", []))
    missing = [n for n in names if n not in exact_names]
    if missing:
        raise ValueError(f"{exact / 'splits.json'}: no exact scene for {missing[:3]} (the two pools must match)")
    out.mkdir(parents=True, exist_ok=True)
    links = {n: recon / n for n in names} | {f"exact_{n}": exact / n for n in names}
    for link, source in links.items():
        link_scene(out / link, source)
    splits = {"train": list(links), "val": [], "test": []}
    (out / "splits.json").write_text(json.dumps(splits, indent=1) + "\n")
    return splits


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recon", type=Path, help="the reconstructed pool view (gspi.recon.reconstructed_pool)")
    parser.add_argument("exact", type=Path, help="the pool view it was reconstructed from")
    parser.add_argument("out", type=Path)
    args = parser.parse_args(argv)
    splits = mix_view(args.recon, args.exact, args.out)
    print(f"{args.out}: {len(splits['train'])} training scenes")


if __name__ == "__main__":
    main()
