"""The field's dataset layouts gspi reads and writes (docs/DATA.md, "Datasets of the field").

One module per layout, each with an importer (layout folder -> canonical scene) and an exporter
(canonical scene -> layout folder); the NeRF-synthetic one is gspi.data.layouts.nerf_synthetic. This
module only names them and recognises a folder's layout from its files (`detect_format`).
"""
from __future__ import annotations

import re
from pathlib import Path

from eval.common.layout import LayoutError

FORMATS = ("nerf_synthetic", "tensoir", "stanford_orb", "nero_glossy")
TENSOIR_VIEW = re.compile(r"^(train|val|test)_\d+$")
SIGNATURES = {  # what detect_format looks for, for its error message
    "tensoir": "train_NNN/metadata.json or test_NNN/metadata.json",
    "stanford_orb": "transforms_train.json with a train_mask/ or test_mask/ folder",
    "nerf_synthetic": "transforms_{train,val,test}.json",
    "nero_glossy": "<k>-camera.pkl",
}


def is_glossy_real(src: Path) -> bool:
    """NeRO's Glossy Real capture: COLMAP cameras, a reference point cloud, photos."""
    return (src / "colmap" / "sparse" / "0").is_dir() and (src / "object_point_cloud.ply").is_file()


def refuse_glossy_real(src: Path) -> None:
    """One line for a NeRO Glossy Real folder, which gspi does not read (why, in the message)."""
    if is_glossy_real(src):
        raise LayoutError(f"{src}: a NeRO Glossy Real capture (colmap/sparse/0, object_point_cloud.ply): not "
                          "supported; its cameras are COLMAP binaries normalised by a per-object table in "
                          "NeRO's code (GlossyRealDatabase.meta_info) and it has no masks "
                          "(GlossyRealDatabase.get_mask raises NotImplementedError); gspi reads NeRO's Glossy "
                          "Synthetic layout (<k>.png, <k>-camera.pkl, <k>-depth.png)")


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
    refuse_glossy_real(src)
    raise LayoutError(f"{src}: no dataset layout recognised (looked for "
                      + "; ".join(f"{k}: {v}" for k, v in SIGNATURES.items()) + "); set import.format")
