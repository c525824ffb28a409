"""Method choice comes from config: conf/method/<name>.yaml's ``_target_`` (gspi/run/methods.py)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from gspi.run.methods import (ExternalMethod, GspiMethod, InhouseMethod, LightFitMethod, Method,
                              MethodUnavailable, build_method)

CONF = Path(__file__).resolve().parents[1] / "conf" / "method"
EXPECTED = {"gspi": GspiMethod, "light_fit": LightFitMethod, "no_decomposition": InhouseMethod, "joint_ir": InhouseMethod,
            "gs_ir": ExternalMethod, "r3dg": ExternalMethod, "gaussianshader": ExternalMethod,
            "irgs": ExternalMethod, "lumigauss": ExternalMethod, "materialanything": ExternalMethod}


def method_cfg(name: str) -> dict:
    return yaml.safe_load((CONF / f"{name}.yaml").read_text())


def test_every_method_file_names_its_class():
    assert {p.stem for p in CONF.glob("*.yaml")} == set(EXPECTED)
    for name, cls in EXPECTED.items():
        cfg = method_cfg(name)
        assert "kind" not in cfg
        method = build_method(cfg, {"data_dir": "."}, Path("."))
        assert type(method) is cls and method.name == name and "_target_" not in method.cfg
        assert method.needs_asset == (cls is not ExternalMethod)
        assert method.reports_own_runtime == (cls is ExternalMethod)


def test_build_method_rejects_missing_or_foreign_targets():
    with pytest.raises(ValueError, match="no _target_"):
        build_method({"name": "x"}, {}, Path("."))
    with pytest.raises(ValueError, match="is not a gspi.run.methods.Method"):
        build_method({"name": "x", "_target_": "pathlib.Path"}, {}, Path("."))
    with pytest.raises(ImportError):
        build_method({"name": "x", "_target_": "gspi.run.methods.NoSuchMethod"}, {}, Path("."))


class Constant(Method):
    needs_asset = False


def test_a_new_method_is_a_target_not_a_branch():
    method = build_method({"name": "c", "_target_": f"{__name__}.Constant"}, {}, Path("."))
    assert type(method) is Constant and method.prepare() == {} and not method.needs_asset
    with pytest.raises(NotImplementedError):
        method.predict(None, Path("."), asset=None, clock=None, work_dir=Path("."), split="test")


def test_no_decomposition_prepare_is_the_baselines_own(tmp_path):
    (tmp_path / "splits.json").write_text(json.dumps({"test": ["a"]}))  # no training scenes
    method = build_method(method_cfg("no_decomposition"), {"data_dir": str(tmp_path)}, tmp_path)
    record = method.prepare()
    assert record["constants"] == {"roughness": 0.5071, "metallic": 0.1865}
    assert "fallback" in record["constants_source"] and method.shared == {"constants": record["constants"]}
    joint = build_method(method_cfg("joint_ir"), {"data_dir": str(tmp_path)}, tmp_path)
    assert joint.prepare() == {} and joint.shared == {}  # baselines.joint_ir has no prepare


def test_external_without_outputs_is_unavailable():
    method = build_method(method_cfg("gs_ir"), {"data_dir": "."}, Path("."))
    with pytest.raises(MethodUnavailable, match="method.outputs"):
        method.prepare()


def test_external_systems_and_their_adapters_come_from_the_method_files():
    from baselines.adapter import Adapter, get_adapter, load_method_config, systems

    assert systems() == sorted(n for n, cls in EXPECTED.items() if cls is ExternalMethod)
    for name in systems():
        adapter = get_adapter(name)
        assert isinstance(adapter, Adapter) and type(adapter).__name__ == method_cfg(name)["adapter"].rpartition(".")[2]
    for not_external in ("gspi", "no_decomposition", "nope"):
        with pytest.raises(ValueError, match="unknown system"):
            load_method_config(not_external)


def test_inhouse_baselines_get_the_runs_device(monkeypatch):
    """gspi-run method=joint_ir device=...: the baseline is called with the run's resolved device."""
    import torch

    from gspi.device import resolve_device
    from gspi.stage_clock import StageClock

    method = build_method(method_cfg("joint_ir"), {"data_dir": ".", "device": "auto"}, Path("."))
    seen = {}

    def fake_predict_scene(*args, device, **kwargs):
        seen["device"] = device
        return {}

    monkeypatch.setattr(method.module, "predict_scene", fake_predict_scene)
    method.predict(None, Path("."), asset=None, clock=StageClock("s"), work_dir=Path("."), split="test")
    assert seen["device"] == resolve_device("auto") and isinstance(seen["device"], torch.device)


def test_the_stage_configs_are_parsed_once_at_the_door(monkeypatch):
    """check_run_config returns the checked stage configs; a method built with them hands them to
    its stages as they are (no second parse), and parses once itself only when built without them."""
    from gspi.run.config_check import StageConfigs, check_run_config
    from gspi.stage1.config import Stage1Config
    from gspi.stage3.config import Stage3Config

    cfg = {"split": "test", "data_dir": "d", "out": "o", "stage1": {}, "stage3": {}}
    stages = check_run_config(cfg)
    assert isinstance(stages, StageConfigs) and stages.stage2 is None and stages.recon is None
    assert isinstance(stages.stage1, Stage1Config) and isinstance(stages.stage3, Stage3Config)
    method = build_method(method_cfg("light_fit"), cfg, Path("."), stages)

    def no_second_parse(*_a, **_k):
        raise AssertionError("a stage config parsed twice")

    monkeypatch.setattr(Stage1Config, "from_dict", classmethod(no_second_parse))
    method.prepare()
    assert method.shared["stage1"] is stages.stage1 and method.shared["stage3"] is stages.stage3
    unparsed = build_method(method_cfg("light_fit"), cfg, Path("."))
    with pytest.raises(AssertionError, match="parsed twice"):
        unparsed.stages  # noqa: B018 - built without them: it parses (here: the patched parser) on first use
