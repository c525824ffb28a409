"""The known-light study's tables are what its committed scores say (``tables.py --check``), and
its scene groups are the held-out pool's (the metal class: 7 scenes; objects of several parts: 18)."""
from __future__ import annotations

from experiments.known_light import tables


def test_committed_tables_are_fresh():
    tables.main(["--check"])


def test_scene_groups():
    assert len(tables.METAL_SCENES) == 7 and len(tables.PARTS_SCENES) == 18
    ious = {"p0224_sphere_metal": 1.0, "p0231_sphere_painted_metal": 0.5, "p0250_blob_ceramic": None,
            "p0239_torus_fabric": 0.0}
    assert tables.iou_mean(ious, tables.METAL_SCENES) == 1.0
    assert tables.iou_mean(ious, tables.PARTS_SCENES) == 0.75  # a parts scene without metal (None) is left out
