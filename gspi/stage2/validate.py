"""Validation while Stage II trains: Table 2's measure on the validation scenes, logged to
``metrics.jsonl`` every ``stage2.validate.every`` steps, and the best EMA weights kept as
``best.pt`` (issue #15: "keep a validation score in the training log so a run's best
checkpoint is known").

The measure is ``gspi.stage2.points_measure``'s (per-view masked PSNR capped at 60 dB, SSIM,
LPIPS of the predictions scattered into the 32 lattice views), made cheap enough to repeat:
``num_steps`` DDIM steps (10 by default) on a seeded subset of ``max_points`` points per
scene whose values are propagated to the whole cloud by 1-NN (``gspi.point_cloud
.nearest_fill``, as ``stage2.inference.max_points`` does at inference). It draws from its own
seeded generators and reads only the EMA weights, so a run with validation trains exactly as
one without (tested). The selection score is the mean PSNR over albedo, roughness, metallic.

A saved model under the same measure: ``python -m gspi.stage2.evaluate_points CHECKPOINT DATASET
OUT --split val --num-steps 10 --max-points 20000`` (the one CLI of the measure).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from gspi.stage2.data import PointDataConfig, ScenePoints
from gspi.stage2.points_measure import average_scores, scatter_to_views, score_maps, subset_prediction

SCORE_KEY = "stage2/val/avg_psnr"


@dataclass
class ValidationConfig:
    """``stage2.validate``."""

    every: Optional[int] = None        # steps between validations (and at the end); null = off
    data: Optional[str] = None         # dataset of the scored scenes; null = the training dataset
    split: str = "val"                 # its split scored
    num_steps: int = 10                # DDIM steps (Table 2 proper: 50)
    max_points: Optional[int] = 20000  # per scene: seeded subset + 1-NN fill; null = every point
    seed: int = 0

    RANGES: ClassVar[dict] = {"every": (1, None), "num_steps": (1, None), "max_points": (1, None),
                              "seed": (0, None)}
    CHOICES: ClassVar[dict] = {"split": ("train", "val", "test")}


class Validator:
    """Scores a model on fixed validation scenes; remembers the best score."""

    def __init__(self, cfg: ValidationConfig, scenes: list[ScenePoints], data_cfg: PointDataConfig):
        from eval.lpips.net import load_lpips

        if not scenes:
            raise ValueError(f"stage2.validate: split {cfg.split!r} has no scenes")
        self.cfg, self.scenes, self.data_cfg = cfg, scenes, data_cfg
        self.lpips = load_lpips()

    def due(self, step: int, last_step: int) -> bool:
        return self.cfg.every is not None and (step % self.cfg.every == 0 or step == last_step)

    def score(self, model) -> dict[str, float]:
        """{"stage2/val/<channel>_<metric>": mean over scenes} for albedo, roughness, metallic
        and their "avg"; model: the EMA denoiser (eval mode)."""
        from gspi.data.gt_maps import read_gt_view_maps

        scores = []
        for i, scene in enumerate(self.scenes):
            maps, mask = scatter_to_views(subset_prediction(model, scene, i, self.data_cfg, self.cfg), scene)
            scores.append(score_maps(maps, read_gt_view_maps(scene.root)[0], mask, self.lpips))
        mean = average_scores(scores)
        return {f"stage2/val/{c}_{m}": v for c, metrics in mean.items() for m, v in metrics.items()}
