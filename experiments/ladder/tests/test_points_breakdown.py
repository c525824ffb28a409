"""experiments/ladder/points_breakdown.py: Table 2's scores per material class and image size."""
from __future__ import annotations

import json

import numpy as np
import pytest


def test_breakdown_by_material_class_and_image_size(tmp_path):
    from experiments.ladder.points_breakdown import breakdown, material_class, to_markdown

    assert material_class("p0230_multipart_painted_metal") == "painted_metal"
    assert material_class("p0231_blob_metal") == "metal" and material_class("x") == "other"
    scenes = ("p0001_blob_metal", "p0002_sphere_metal", "p0003_torus_fabric")
    data = tmp_path / "data"
    for scene, width in zip(scenes, (64, 128, 128)):
        (data / scene).mkdir(parents=True)
        (data / scene / "scene.json").write_text(json.dumps({"width": width}))
    value = {"p0001_blob_metal": 10.0, "p0002_sphere_metal": 20.0, "p0003_torus_fabric": 30.0}
    for ablation, offset in (("full", 0.0), ("a1_no_global_prior", -1.0)):
        folder = tmp_path / ablation
        folder.mkdir()
        ps = {s: {c: {"psnr": value[s] + offset + i, "ssim": 0.5, "lpips": 0.1}
                  for i, c in enumerate(("albedo", "roughness", "metallic"))} for s in scenes}
        (folder / "scores.json").write_text(json.dumps({
            "format": "gspi-points-eval", "ablation": ablation, "data": str(data), "split": "test",
            "scenes": list(scenes), "per_scene": {"stage2": ps, "no_decomposition": ps}}))
    table = breakdown([tmp_path / "full", tmp_path / "a1_no_global_prior"])
    assert table["full"]["class=metal"] == pytest.approx(16.0)      # (11 + 21) / 2
    assert table["full"]["size=128"] == pytest.approx(26.0)         # (21 + 31) / 2
    assert table["a1_no_global_prior"]["metallic"] == pytest.approx(np.mean([11, 21, 31]))
    assert table["no_decomposition"]["class=fabric"] == pytest.approx(31.0)  # a1's baseline not added twice
    assert "| full |" in to_markdown(table)
    metallic = breakdown([tmp_path / "full"], channel="metallic")
    assert metallic["full"]["class=metal"] == pytest.approx(17.0)   # (12 + 22) / 2
