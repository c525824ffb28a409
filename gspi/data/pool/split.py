"""A dataset view of a Stage II training pool: chosen pool scenes as train / val / test splits.

The pool (`gspi.data.pool.training_pool`) lists every scene under "train". Experiments that train
on part of it and score on scenes it never saw (Table 2 at CPU scale, docs/log/diary.md) need a
dataset folder whose splits say so. This writes one without copying anything: a symlink per
scene and a `splits.json`, ranges by pool index, disjoint by construction (overlap is refused):

    python -m gspi.data.pool.split ~/.cache/gspi/stage2_pool data/pool64 --train 0:64
    python -m gspi.data.pool.split ~/.cache/gspi/stage2_pool data/heldout32 --train 0:64 --test 224:256

Only complete pool scenes (their `complete.json` exists) are used; a range reaching past the
pool, or an unfinished scene inside it, is an error that names it. The view's prior-feature
cache (`<out>/.cache`) is its own.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from eval.common.errors import MissingInputError
from eval.common.layout import LayoutError
from gspi.data.pool.training_pool import is_complete

SPLITS = ("train", "val", "test")


def parse_range(text: str) -> range:
    """"a:b" -> range(a, b) (pool indices, b exclusive)."""
    try:
        start, stop = (int(x) for x in text.split(":"))
    except ValueError as exc:
        raise ValueError(f"pool range {text!r}: expected START:STOP, e.g. 0:64") from exc
    if not 0 <= start < stop:
        raise ValueError(f"pool range {text!r}: need 0 <= START < STOP")
    return range(start, stop)


def pool_scenes(pool: Path) -> dict[int, str]:
    """{pool index: scene name} of the pool's splits.json (its "train" list)."""
    splits = pool / "splits.json"
    if not splits.is_file():
        raise MissingInputError(f"{splits}: not found ({pool} is not a Stage II training pool)")
    names = json.loads(splits.read_text()).get("train") or []
    return {int(name[1:5]): name for name in names}


def link_scene(link: Path, target: Path) -> None:
    """A view's scene: ``link`` -> ``target`` (absolute); an existing ``link`` must already lead there."""
    target = target.resolve()
    if link.is_symlink() or link.exists():
        if link.resolve() != target:
            raise FileExistsError(f"{link}: exists and is not a link to {target}")
        return
    os.symlink(target, link)


def split_view(pool: str | Path, out: str | Path, ranges: dict[str, range]) -> dict[str, list[str]]:
    """Writes the view (symlinks + splits.json) and returns its splits."""
    pool, out = Path(pool).resolve(), Path(out)
    by_index = pool_scenes(pool)
    chosen = {split: list(ranges.get(split, range(0))) for split in SPLITS}
    for a in SPLITS:
        for b in SPLITS[SPLITS.index(a) + 1:]:
            common = set(chosen[a]) & set(chosen[b])
            if common:
                raise LayoutError(f"splits {a} and {b} share pool indices {sorted(common)[:5]}...")
    splits = {}
    for split, indices in chosen.items():
        missing = [i for i in indices if i not in by_index]
        if missing:
            raise LayoutError(f"{pool}: has no pool scene {missing[0]} ({split} range ends at "
                             f"{indices[-1] + 1}, the pool has {len(by_index)} scenes)")
        unfinished = [by_index[i] for i in indices if not is_complete(pool / by_index[i])]
        if unfinished:
            raise LayoutError(f"{pool / unfinished[0]}: unfinished pool scene (no complete.json); "
                             "rerun the pool generation first")
        splits[split] = [by_index[i] for i in indices]
    out.mkdir(parents=True, exist_ok=True)
    for name in (n for names in splits.values() for n in names):
        link_scene(out / name, pool / name)
    (out / "splits.json").write_text(json.dumps(splits, indent=1) + "\n")
    return splits


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pool")
    parser.add_argument("out")
    for split in SPLITS:
        parser.add_argument(f"--{split}", type=parse_range, help="pool indices START:STOP")
    args = parser.parse_args(argv)
    ranges = {s: getattr(args, s) for s in SPLITS if getattr(args, s) is not None}
    splits = split_view(args.pool, args.out, ranges)
    print(json.dumps({k: len(v) for k, v in splits.items()}))


if __name__ == "__main__":
    from eval.common.errors import run_command

    run_command(main)  # a stated error or Ctrl-C: one line (exit 2 / 130)
