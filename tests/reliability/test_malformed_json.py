"""Class 7, malformed JSON: a data or result file that is not the object the layout describes
(a list, wrong types, truncated, nested 100,000 deep) is refused with the file's name, never a
raw Python error (AttributeError, TypeError, RecursionError) without one."""
from __future__ import annotations

import json

import pytest

from tests.reliability.helpers import EVAL_FAST, assert_fails_naming, run_cli

DEEP = "[" * 100_000 + "]" * 100_000


META_CASES = {"list": "[1, 2]", "runtime_string": json.dumps({"method": "m", "runtime_s": "fast"}),
              "method_number": json.dumps({"method": 3, "runtime_s": {}}),
              "runtime_nan": '{"method": "m", "runtime_s": {"material": NaN}}',
              "truncated": '{"method": "m", "runt', "deep": DEEP}


@pytest.mark.parametrize("case", sorted(META_CASES))
def test_gspi_eval_names_a_malformed_meta_json(workspace, case):
    from eval.cli import main

    meta = workspace / "pred" / "sphere_0" / "meta.json"
    meta.write_text(META_CASES[case])
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, str(meta))


SCENE_CASES = {"list": "[]", "views_list": None, "width_string": None, "deep": DEEP, "truncated": '{"name": '}


@pytest.mark.parametrize("case", sorted(SCENE_CASES))
def test_gspi_eval_names_a_malformed_scene_json(workspace, case):
    from eval.cli import main

    path = workspace / "gt" / "sphere_0" / "scene.json"
    data = json.loads(path.read_text())
    if case == "views_list":
        data["views"] = [1]
    elif case == "width_string":
        data["width"] = "wide"
    path.write_text(SCENE_CASES[case] if SCENE_CASES[case] is not None else json.dumps(data))
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, str(path))


SUMMARY_CASES = {"truncated": '{"albedo": {"psnr": 2', "list": "[1]", "deep": DEEP,
                 "nan": '{"roughness": {"psnr": NaN, "ssim": 0.5, "lpips": 0.1}}',
                 "string": '{"roughness": {"psnr": "high", "ssim": 0.5, "lpips": 0.1}}',
                 "channel_list": '{"roughness": [1, 2]}'}


@pytest.mark.parametrize("case", sorted(SUMMARY_CASES))
def test_gspi_table_names_a_malformed_summary_json(tmp_path, case):
    """A NaN showed as `--` ("not modelled"); a list or truncated file gave a raw error."""
    from eval.tables.cli import main

    ev = tmp_path / "ev"
    ev.mkdir()
    (ev / "summary.json").write_text(SUMMARY_CASES[case])
    (ev / "eval_meta.json").write_text(json.dumps({"method": "m", "protocol": {"name": "p", "version": 1}}))
    code, text = run_cli(main, [str(ev), f"out={tmp_path / 'tables'}"])
    assert_fails_naming(code, text, str(ev / "summary.json"))
    assert not (tmp_path / "tables" / "table1.md").exists()


@pytest.mark.parametrize("content", ["[1]", DEEP, '{"format": "gspi-run"'])
def test_gspi_table_names_a_malformed_run_record(tmp_path, content):
    from eval.tables.cli import main

    job = tmp_path / "sweep" / "job"
    (job / ".hydra").mkdir(parents=True)
    (job / "result.json").write_text(content)
    code, text = run_cli(main, [str(tmp_path / "sweep"), f"out={tmp_path / 'tables'}"])
    assert_fails_naming(code, text, str(job / "result.json"))


def test_gspi_run_reads_a_deep_record_as_absent(tmp_path):
    """The runner treats an unreadable record as "no result" (it then redoes the job)."""
    from gspi.run.record import is_complete, read_result

    (tmp_path / "result.json").write_text(DEEP)
    assert read_result(tmp_path) is None and not is_complete(tmp_path, "h")
