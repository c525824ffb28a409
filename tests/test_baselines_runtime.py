"""External systems' runtime split into geometry and material (baselines/runtime.py)."""
import json

import pytest

from baselines import adapter as adapter_module
from baselines.adapter import get_adapter, load_method_config
from baselines.runtime import command_stages, given_runtime, split_seconds
from eval.common.layout import read_meta
from tests.adapter_fixtures import gt_maps, write_gs_ir
from tests.fixtures import make_scene


def test_split_by_command_stage_hand_computed():
    assert split_seconds([600.0, 60.0, 300.0, 40.0], ["geometry", "material", "material", "material"]) == \
        {"geometry": 600.0, "material": 400.0, "end_to_end": 1000.0}
    assert split_seconds([600.0, 400.0], None) == {"geometry": None, "material": None, "end_to_end": 1000.0}
    # geometry made elsewhere (MaterialAnything's mesh): material only, end-to-end unknown
    assert split_seconds([90.0, 0.5], ["material", "material"]) == \
        {"geometry": None, "material": 90.5, "end_to_end": None}
    assert given_runtime(1000) == {"geometry": None, "material": None, "end_to_end": 1000.0}
    assert given_runtime({"geometry": 600, "material": 400}) == \
        {"geometry": 600.0, "material": 400.0, "end_to_end": 1000.0}


def test_command_stages_are_validated():
    cfg = load_method_config("r3dg")
    assert command_stages(cfg, 3) == ["geometry", "material", "material"]
    with pytest.raises(ValueError, match="one stage per command"):
        command_stages({**cfg, "command_stages": ["geometry"]}, 3)
    with pytest.raises(ValueError, match=r"command_stages has \['shape'\]; allowed: geometry, material"):
        get_adapter("r3dg").commands("d", "m", {**cfg, "command_stages": ["shape", "material", "material"]})
    with pytest.raises(ValueError, match="runtime_s="):
        given_runtime({"geometry": 1.0, "total": 2.0})
    for system in ("gs_ir", "r3dg", "irgs", "gaussianshader", "lumigauss", "materialanything"):
        cfg = load_method_config(system)  # every shipped recipe is consistent
        command_stages(cfg, len(cfg["commands"]))


def test_timed_run_records_geometry_and_material(tmp_path, monkeypatch):
    """GS-IR's 4 commands 'take' 600, 60, 300, 40 s (a fake clock): geometry = stage 1, material
    = baking + stage 2 + render, end-to-end = all; the import writes them to meta.json."""
    clock = iter([0.0, 600.0, 600.0, 660.0, 660.0, 960.0, 960.0, 1000.0])
    monkeypatch.setattr(adapter_module.time, "perf_counter", lambda: next(clock))
    monkeypatch.setattr(adapter_module.subprocess, "run", lambda *a, **k: None)
    scene = make_scene(tmp_path / "gt", "ball", size=20, seed=1, num_test=3)
    model = write_gs_ir(tmp_path / "model", gt_maps(scene))
    adapter, cfg = get_adapter("gs_ir"), {**load_method_config("gs_ir"), "checkout": str(tmp_path)}
    assert adapter.run(tmp_path / "data", model, cfg, dry_run=False, echo=lambda _: None) == 1000.0
    record = json.loads((model / "gspi_runtime.json").read_text())
    assert record["command_seconds"] == [600.0, 60.0, 300.0, 40.0]
    pred = adapter.import_outputs(model, scene.root, tmp_path / "pred", cfg)
    assert read_meta(pred)["runtime_s"] == {"material": 400.0, "end_to_end": 1000.0, "geometry": 600.0}


def test_table_cell_says_total_only(tmp_path):
    """Table 1's runtime cell: "material (end-to-end)", or "T total only" for a joint run."""
    import json

    from eval.tables.sources import load_eval_folders
    from eval.tables.render import to_markdown
    from eval.tables.build import TABLE_SPECS, build_sweep_table

    scores = {c: {"psnr": 20.0, "ssim": 0.5, "lpips": 0.1} for c in ("albedo", "relight")}
    for name, runtime in (("joint", {"material": None, "end_to_end": 16.7}),
                          ("split", {"material": 6.7, "end_to_end": 16.7}), ("none", {})):
        d = tmp_path / name
        d.mkdir()
        (d / "summary.json").write_text(json.dumps(scores))
        (d / "eval_meta.json").write_text(json.dumps({"method": name, "runtime_min": runtime,
                                                      "protocol": {"name": "p", "version": 1}}))
    sweep = load_eval_folders([tmp_path])
    rows = {line.split(" | ")[0][2:]: line for line in
            to_markdown(build_sweep_table(sweep, TABLE_SPECS["table1"]), sweep).splitlines()
            if line.startswith("| ") and not line.startswith("| Method")}
    assert "16.7 total only" in rows["joint"]
    assert "6.7** (16.7)" in rows["split"]  # the fastest material time is bold
    assert "total only" not in rows["none"] and " -- | 1 |" in rows["none"]


def test_gspi_import_takes_a_split_runtime(tmp_path):
    from omegaconf import OmegaConf

    from baselines.cli import run_import

    scene = make_scene(tmp_path / "gt", "ball", size=20, seed=1, num_test=3)
    model = write_gs_ir(tmp_path / "model", gt_maps(scene))
    cfg = OmegaConf.create({"method": load_method_config("gs_ir"), "src": str(model), "scene": str(scene.root),
                            "out": str(tmp_path / "pred"), "split": "test",
                            "runtime_s": {"geometry": 60.0, "material": 30.0}})
    run_import(cfg)
    assert read_meta(tmp_path / "pred" / scene.name)["runtime_s"] == \
        {"material": 30.0, "end_to_end": 90.0, "geometry": 60.0}
