"""What the Stage II recipe goldens share (tests/test_stage2_recipes.py and the studies' recipe
tests): the keys added after a golden was recorded, and a recipe's composed stage2 section
without them."""
from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from eval.common.conf import CONF_DIR

from eval.config import register_configs

# keys added after the golden was recorded, each off in every recipe (issues 52, 66): (section, key) -> off value
ADDED_OFF = {("data", "cross_view_radiance"): False, ("data", "cross_view_neighbourhood"): False,
             ("data", "light_readout"): False, ("data", "light_wrong_share"): 0.0,
             ("data", "light_candidates"): "procedural", ("data", "light_env_height"): 64,
             ("data", "light_geometry"): "cloud", ("data", "light_normal_search_deg"): None,
             ("data", "light_normal_profile"): 1, ("data", "light_metal_min_evidence"): None,
             ("data", "subset"): "local", ("inference", "patch_points"): None, ("inference", "patch_coverage"): 2.0,
             ("inference", "light_views"): "photos",  # light_views: read only by a light_readout model
             ("inference", "points_per_gaussian"): None, ("diffusion", "readout_metal_gate"): False}


def composed_stage2(*overrides: str, study_conf: Path | None = None) -> dict:
    """gspi-train's composed stage2 section under ``overrides`` (with a study's conf folder on the
    search path), without ``ADDED_OFF``'s keys, after checking they are off."""
    register_configs()
    search = [f"hydra.searchpath=[file://{study_conf}]"] if study_conf else []
    with initialize_config_dir(version_base="1.3", config_dir=str(CONF_DIR)):
        cfg = OmegaConf.to_container(compose("gspi_train", overrides=[*search, *overrides]).stage2, resolve=True)
    for (section, key), off in ADDED_OFF.items():
        assert cfg[section].pop(key) == off, f"{' '.join(overrides)}: stage2.{section}.{key} is not off"
    return cfg
