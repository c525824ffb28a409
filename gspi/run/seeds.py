"""The run's ``seed`` in every stage that draws random numbers.

Each stage seeds its own generator from its config key (``stage1.seed``: the point subsample;
``stage2.inference.seed``: DDIM noise and subset; ``stage3.seed``: the view order; a baseline's
``method.seed``). A job's ``seed`` offsets each of them, so ``gspi-run seed=1`` is another draw of
the whole method while a key set on its own still moves its stage alone. Before session 30 only
the global torch/numpy RNGs saw ``seed``, so with shipped assets and a shipped Stage II model
``seed=1`` gave seed 0's bytes (Table 3's seeds came out identical).

Left out on purpose: ``recon.seed`` (Stage 0 makes the 2DGS asset GS-PI takes as input: every
seed of a job starts from the same asset, as with ``assets=``) and the evaluation noise of a
training's validation / test measure (``stage2.validate.seed``, ``stage2.eval.seed``).

Done on the resolved job config rather than as ``${seed}`` interpolations in the stage files:
those files are also loaded on their own (the stage CLIs, the dataclass checks), where a
top-level ``seed`` does not exist.
"""
from __future__ import annotations

import copy
from collections.abc import Mapping, MutableMapping
from typing import Any

# (path of the key in the job config); a path whose node is absent is skipped
STAGE_SEED_KEYS: tuple[tuple[str, ...], ...] = (
    ("stage1", "seed"), ("stage2", "inference", "seed"), ("stage3", "seed"), ("method", "seed"))


def with_run_seed(cfg: Mapping[str, Any]) -> dict:
    """A copy of the job config ``cfg`` with each ``STAGE_SEED_KEYS`` seed offset by ``cfg['seed']``
    (unchanged at seed 0)."""
    out = copy.deepcopy(dict(cfg))
    run_seed = out.get("seed", 0)
    if not isinstance(run_seed, int) or isinstance(run_seed, bool) or run_seed == 0:
        return out  # 0: nothing to offset; not an integer: check_run_config names the key
    for path in STAGE_SEED_KEYS:
        node = out
        for key in path[:-1]:
            node = node.get(key) if isinstance(node, Mapping) else None
        if isinstance(node, MutableMapping) and isinstance(node.get(path[-1]), int):
            node[path[-1]] += run_seed  # a bad value is left for check_run_config to name
    return out
