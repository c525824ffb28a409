"""The scenes of one dataset split as Stage II reads them: ``ScenePoints`` with their cached
global-prior features (``gspi.stage2.feature_cache``). Training, validation, Table 2's measure
(and a study's predictors) all load their scenes here."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from gspi.stage2.data import ScenePoints, load_scene_points
from gspi.stage2.feature_cache import scene_feature_maps, scene_prior_features


def cache_dir(cfg: Mapping[str, Any]) -> Path:
    """``stage2.prior.cache_dir``, default ``<data>/.cache/stage2_prior``."""
    return Path(cfg["stage2"].prior.cache_dir or Path(cfg["data_dir"]) / ".cache" / "stage2_prior")


def load_split(cfg: Mapping[str, Any], split: str, encoder, *, conditions: bool = True,
               light_source: str = "capture", told_light: str = "estimated") -> list[ScenePoints]:
    """ScenePoints (+ cached prior features) of every scene of ``split`` in ``cfg.data``; with
    ``stage2.data.pixel_features`` / ``pixel_feature_spread`` also the encoder's unpooled maps, unless ``conditions`` is
    False (scenes read for their ground truth only, e.g. the no-decomposition baseline's).
    ``light_source``: the light ``stage2.data.light_readout`` is told: ``capture`` (the scene's own,
    training) or ``estimated`` (among the model's candidates, as at inference: Table 2's measure);
    ``told_light``: with ``estimated``, the estimate or a deliberately wrong light
    (``points_measure.told_light``, ``light_condition.mistold_light``)."""
    from eval.common.layout import read_splits

    data_dir = Path(cfg["data_dir"])
    names = read_splits(data_dir).get(split, [])
    if not names:
        raise ValueError(f"{data_dir / 'splits.json'}: split {split!r} is empty")
    maps = conditions and cfg["stage2"].data.needs_feature_maps
    scenes = [load_scene_points(data_dir / n, scene_prior_features(data_dir / n, encoder, cache_dir(cfg)),
                                scene_feature_maps(data_dir / n, encoder, cache_dir(cfg)) if maps else None)
              for n in names]
    for scene in scenes:
        scene.light_source, scene.told_light = light_source, told_light
        scene.light_cache = cache_dir(cfg)  # the read-out's table kept beside the prior's features
    return scenes
