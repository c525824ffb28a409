"""gspi-points-eval: Table 2's measure of a saved Stage II model, under a named measure.

Examples:
    gspi-points-eval checkpoint=runs/s2/checkpoint.pt data=DATA out=runs/s2/eval
    gspi-points-eval checkpoint=... data=HELDOUT out=... baseline=results/table2/cpu/full_s0/scores.json
    gspi-points-eval checkpoint=... data=... out=... points_measure.num_steps=50

The measure's knobs come from conf/points_measure/<name>.yaml (``table2``: 10 DDIM steps, a seeded
20 000-point subset + 1-NN fill, seed 0), checked once (``eval.points_protocol``); ``scores.json``
records them and ``measure_protocol: {name, hash}``. The scoring is
``gspi.stage2.evaluate_points.evaluate_checkpoint``, which ``python -m gspi.stage2.evaluate_points``
also calls with the knobs as flags.

Config: conf/gspi_points_eval.yaml, conf/points_measure/.
"""
from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli
from eval.common.errors import MissingInputError


def run(cfg: DictConfig) -> dict:
    """Measures ``cfg.checkpoint`` on ``cfg.data_dir`` into ``cfg.out``; returns the scores."""
    import torch

    from eval.points_protocol import measure_knobs
    from gspi.stage2.checkpoint import load_stage2_checkpoint
    from gspi.stage2.evaluate_points import checkpoint_source, evaluate_checkpoint

    measure = OmegaConf.to_container(cfg.points_measure, resolve=True)
    knobs = measure_knobs(measure)  # checked before the model loads
    for key in ("checkpoint", "data_dir") + (("baseline",) if cfg.baseline else ()):
        if not Path(cfg[key]).exists():
            raise MissingInputError(f"{key}={cfg[key]}: does not exist")
    torch.set_num_threads(int(cfg.threads))
    model, train_cfg = load_stage2_checkpoint(cfg.checkpoint)
    result = evaluate_checkpoint(model, train_cfg, cfg.data_dir, cfg.out, **knobs,
                                 source=checkpoint_source(cfg.checkpoint), baseline_train=cfg.baseline,
                                 measure_name=measure.get("name"))
    print((Path(cfg.out) / "table.md").read_text())
    return result


main = hydra_cli(run, "gspi_points_eval", path_keys=("checkpoint", "data_dir", "out", "baseline"))


if __name__ == "__main__":
    main()
