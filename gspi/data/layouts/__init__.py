"""The field's dataset layouts gspi reads and writes (docs/DATA.md, "Datasets of the field").

One module per layout, each with an importer (layout folder -> canonical scene) and an exporter
(canonical scene -> layout folder); the NeRF-synthetic one is gspi.data.nerf_synthetic. This
module only names them and recognises a folder's layout from its files (`detect_format`).
"""
from __future__ import annotations

import re
from pathlib import Path

from eval.layout import LayoutError

FORMATS = ("nerf_synthetic", "tensoir", "stanford_orb", "nero_glossy")
TENSOIR_VIEW = re.compile(r"^(train|val|test)_\d+$")
SIGNATURES = {  # what detect_format looks for, for its error message
    "tensoir": "train_NNN/metadata.json or test_NNN/metadata.json",
    "stanford_orb": "transforms_train.json with a train_mask/ or test_mask/ folder",
    "nerf_synthetic": "transforms_{train,val,test}.json",
    "nero_glossy": "<k>-camera.pkl",
}


def detect_format(src: str | Path) -> str:
    """The layout of folder ``src``, from its files (checked in the order of SIGNATURES).

    Raises:
        LayoutError: one line naming the folder and what each layout would have.
    """
    src = Path(src)
    if not src.is_dir():
        raise LayoutError(f"{src}: import.src folder not found")
    names = {p.name for p in src.iterdir()}
    if any(TENSOIR_VIEW.match(n) and (src / n / "metadata.json").is_file() for n in names):
        return "tensoir"
    transforms = {n for n in names if re.fullmatch(r"transforms_(train|val|test)\.json", n)}
    if transforms and ({"train_mask", "test_mask"} & names):
        return "stanford_orb"
    if transforms:
        return "nerf_synthetic"
    if any(n.endswith("-camera.pkl") for n in names):
        return "nero_glossy"
    raise LayoutError(f"{src}: no dataset layout recognised (looked for "
                      + "; ".join(f"{k}: {v}" for k, v in SIGNATURES.items()) + "); set import.format")
