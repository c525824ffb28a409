"""Class 3, zero-image evaluations: a prediction folder in which nothing matches the layout
(view folders named differently, `Test/`, EXR maps, `eval.channels=[]`) fails, naming what was
looked for; before the fix each gave "images: 0", an empty summary and exit 0, and gspi-table
then printed a row of `--` that reads as "channel not modelled"."""
from __future__ import annotations

import json
import shutil

import pytest

from tests.reliability.helpers import EVAL_FAST, assert_fails_naming, assert_written_only_under, run_cli, snapshot


def _rename_views(pred, fmt):
    for vdir in sorted((pred / "sphere_0" / "test").iterdir()):
        vdir.rename(vdir.with_name(fmt.format(int(vdir.name))))


def _capital_split(pred):
    (pred / "sphere_0" / "test").rename(pred / "sphere_0" / "Test")


def _exr_maps(pred):
    import numpy as np

    from eval.common.imageio import write_exr
    for png in sorted((pred / "sphere_0" / "test").rglob("*.png")):
        write_exr(png.with_suffix(".exr"), np.zeros((32, 32, 1), np.float32))
        png.unlink()


CASES = {"views_t00": lambda p: _rename_views(p, "t{:02d}"), "split_Test": _capital_split, "exr_maps": _exr_maps}


@pytest.mark.parametrize("case", sorted(CASES))
def test_gspi_eval_refuses_a_prediction_with_nothing_to_score(workspace, case):
    from eval.cli import main

    CASES[case](workspace / "pred")
    before = snapshot(workspace)
    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert_fails_naming(code, text, "0 images scored", str(workspace / "pred" / "sphere_0"), "roughness.png")
    assert not (workspace / "ev" / "summary.json").exists()
    assert_written_only_under(before, snapshot(workspace), "ev")


def test_gspi_eval_refuses_empty_channels(workspace):
    from eval.cli import main

    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                "progress=false", "eval.channels=[]"])
    assert_fails_naming(code, text, "eval.channels", "at least one")
    assert not (workspace / "ev" / "summary.json").exists()


def test_gspi_table_refuses_an_empty_summary_left_by_an_old_evaluation(workspace):
    """A summary.json of 0 images (written before the fix) is refused, never a row of `--`."""
    from eval.tables.cli import main

    ev = workspace / "ev"
    ev.mkdir()
    (ev / "summary.json").write_text("{}\n")
    (ev / "eval_meta.json").write_text(json.dumps({"method": "m", "protocol": {"name": "p", "version": 1}}))
    code, text = run_cli(main, [str(ev), f"out={workspace / 'tables'}"])
    assert_fails_naming(code, text, str(ev / "summary.json"), "0 images")


def test_a_correct_prediction_still_scores(workspace):
    """The case that already worked: the same folder, untouched, exits 0 with images > 0."""
    from eval.cli import main

    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST])
    assert code == 0 and "images: 4" in text, text[-2000:]
    shutil.rmtree(workspace / "ev")
