"""benchmarks/bench_pipeline.py's settings: the demo's, read from conf/experiment/demo.yaml (its one
definition), and at ``--preset tiny`` the same with the asset made by recon=tiny (no shipped asset)."""
from __future__ import annotations

from pathlib import Path

import yaml

from benchmarks.bench_pipeline import DEMO, preset_overrides

DEMO_YAML = Path(__file__).resolve().parents[1] / "conf" / "experiment" / "demo.yaml"


def test_the_demo_settings_are_demo_yaml():
    demo = yaml.safe_load(DEMO_YAML.read_text())
    assert f"stage3.iterations={demo['stage3']['iterations']}" in DEMO
    assert f"stage2.inference.num_steps={demo['stage2']['inference']['num_steps']}" in DEMO
    assert f"stage2.inference.points_per_gaussian={demo['stage2']['inference']['points_per_gaussian']}" in DEMO
    assert len([o for o in DEMO if o.startswith(("stage2.", "stage3."))]) == (
        len(demo["stage2"]["inference"]) + len(demo["stage3"]))  # every key it sets, none more
    assert f"assets={demo['assets']}" in DEMO and "recon=fast" in DEMO
    assert preset_overrides("small") == DEMO


def test_tiny_reconstructs_its_asset_and_keeps_the_rest():
    tiny = preset_overrides("tiny")
    assert "recon=tiny" in tiny and not any(o.startswith(("assets=", "recon=fast")) for o in tiny)
    assert "stage1.image_size=64" in tiny  # the lattice at the tiny scenes' size, as the demo's at small's 128
    assert [o for o in tiny if o not in ("recon=tiny", "stage1.image_size=64")] == [
        o for o in DEMO if not o.startswith(("assets=", "recon="))]


def test_material_cpu_sums_the_listed_stages_present(tmp_path):
    import json

    from benchmarks.budget_quality import material_cpu_seconds

    meta = {"stages": {"recon": {"cpu_seconds": 50.0}, "stage1": {"cpu_seconds": 1.5}, "stage2": {"cpu_seconds": 2.0},
                       "stage3": {"cpu_seconds": 0.25}}}
    (tmp_path / "predictions" / "s0").mkdir(parents=True)
    (tmp_path / "predictions" / "s0" / "meta.json").write_text(json.dumps(meta))
    joint = {"stages": {"recon": {"cpu_seconds": 50.0}, "material": {"cpu_seconds": 7.0}}}
    (tmp_path / "predictions" / "s1").mkdir(parents=True)
    (tmp_path / "predictions" / "s1" / "meta.json").write_text(json.dumps(joint))
    assert material_cpu_seconds(tmp_path, ["s0", "s1"]) == {"s0": 3.75, "s1": 7.0}  # Stage 0 is not material time
