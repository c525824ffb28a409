"""The gspi-data config of a preset as the command line composes it (its argv aliases applied),
shared by the dataset tests (tests/test_data_generate.py, test_training_pool.py, test_controlled_pairs.py)."""
from __future__ import annotations

from pathlib import Path

from hydra import compose, initialize_config_dir

from eval.common.argv import apply_aliases
from eval.common.conf import CONF_DIR


def compose_data_config(preset: str, out: Path, seed: int, overrides: list[str]):
    """``gspi-data preset=<preset> out=<out> seed=<seed> <overrides>``'s composed config."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose("gspi_data", overrides=apply_aliases(
            [f"preset={preset}", f"out={out}", f"seed={seed}", *overrides], "gspi_data"))
