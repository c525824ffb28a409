"""The repository's config directory, conf/, as an absolute path: console-script entry points make
Hydra resolve a relative config_path as a Python package, which conf/ is not."""
from pathlib import Path

CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")
