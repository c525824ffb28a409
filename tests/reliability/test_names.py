"""Class 2, names used as paths: a `scene.json` name, a view id, a splits.json entry, a
`scenes=` entry or an import's scene name such as `../../x` is refused (naming the file and
key), and nothing is written outside `out`. One check, eval.common.layout.check_name, guards every
Scene and View however it is made, so no writer (predictions, recon cache, imports, exports)
needs its own."""
from __future__ import annotations

import json

import pytest

from tests.reliability.helpers import EVAL_FAST, assert_fails_naming, assert_written_only_under, run_cli, snapshot

BAD_NAMES = ["../../x", "..", "a/b", "", ".hidden", "a\\b", "tab\there"]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_check_name_refuses_what_is_not_one_path_component(name):
    from eval.common.layout import LayoutError, check_name

    with pytest.raises(LayoutError, match="where.json: .*not allowed as a name"):
        check_name(name, "where.json: key")


@pytest.mark.parametrize("name", ["s000_torus_metal", "t00", "lego", "scène-ü 1", "a=b,c"])
def test_check_name_accepts_ordinary_names(name):
    from eval.common.layout import check_name

    assert check_name(name, "x") == name


def _edit_scene_json(workspace, edit):
    path = workspace / "gt" / "sphere_0" / "scene.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("where", ["name", "view_id", "split"])
def test_gspi_eval_refuses_a_scene_json_name_that_escapes(workspace, where):
    from eval.cli import main

    def edit(data):
        if where == "name":
            data["name"] = "../../escaped"
        elif where == "view_id":
            data["views"]["test"][0]["id"] = "../../escaped"
        else:
            data["views"]["../../escaped"] = data["views"].pop("train")

    edit_path = _edit_scene_json(workspace, edit)
    before = snapshot(workspace.parent)
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, str(edit_path), "../../escaped")
    assert_written_only_under(before, snapshot(workspace.parent), f"{workspace.name}/ev")


def test_gspi_run_refuses_a_splits_entry_that_escapes(micro_dataset, tmp_path):
    import shutil

    from gspi.cli.run import main
    from tests.run_helpers import TINY_RUN

    data = tmp_path / "data"
    shutil.copytree(micro_dataset, data, ignore=shutil.ignore_patterns(".cache"))
    (data / "splits.json").write_text(json.dumps({"train": [], "val": [], "test": ["../../escaped"]}))
    before = snapshot(tmp_path)
    code, text = run_cli(main, [f"data={data}", f"out={tmp_path / 'run'}", *TINY_RUN, "method=no_decomposition"])
    assert_fails_naming(code, text, str(data / "splits.json"), "../../escaped")
    assert_written_only_under(before, snapshot(tmp_path), "run")


def test_gspi_run_refuses_a_scenes_override_that_escapes(micro_dataset, tmp_path):
    from gspi.cli.run import main
    from tests.run_helpers import TINY_RUN

    code, text = run_cli(main, [f"data={micro_dataset}", f"out={tmp_path / 'run'}", *TINY_RUN,
                                "method=no_decomposition", "scenes=[../../escaped]"])
    assert_fails_naming(code, text, "scenes", "../../escaped")
    assert not (tmp_path / "run" / "result.json").exists()


def test_gspi_import_refuses_a_scene_name_that_escapes(workspace):
    """gspi-import writes <out>/<scene name>/: a name `../../x` wrote two levels above `out`."""
    from baselines.cli import import_main

    scene = _edit_scene_json(workspace, lambda d: d.update(name="../../escaped")).parent
    (workspace / "system_out").mkdir()
    before = snapshot(workspace.parent)
    code, text = run_cli(import_main, ["system=r3dg", f"src={workspace / 'system_out'}", f"scene={scene}",
                                       f"out={workspace / 'imported'}"])
    assert_fails_naming(code, text, str(scene / "scene.json"), "../../escaped")
    assert_written_only_under(before, snapshot(workspace.parent), f"{workspace.name}/imported")


def test_gspi_data_import_refuses_a_scene_name_that_escapes(tmp_path):
    """gspi-data import.name=../x would have written the scene outside `out`."""
    from gspi.cli.data import main

    src = tmp_path / "nerf"
    src.mkdir()
    (src / "transforms_test.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": []}))
    before = snapshot(tmp_path)
    code, text = run_cli(main, [f"import.src={src}", "import.name=../escaped", f"out={tmp_path / 'out'}"])
    assert_fails_naming(code, text, "../escaped")
    assert not (tmp_path / "escaped").exists()
    assert_written_only_under(before, snapshot(tmp_path), "out")
