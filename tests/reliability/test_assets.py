"""Class 5, degenerate assets (an asset 1e6 units away, huge scales, no surfels) and black
predictions: refused naming the PLY or the prediction folder, where they used to run to
"complete" with black maps; and class 10's PLY cases (a header declaring fewer vertices than
the file holds, overflowing log scales), which used to be read silently or reach Stage I's
misleading "check the asset's scale and position"."""
from __future__ import annotations

import json

import pytest
import torch

from tests.reliability.helpers import assert_fails_naming, run_cli
from tests.run_helpers import TINY_RUN


def _test_scene(micro_dataset):
    from eval.common.layout import read_scene

    name = json.loads((micro_dataset / "splits.json").read_text())["test"][0]
    return read_scene(micro_dataset / name)


def _asset(kind: str):
    from gspi.gaussians.model import Gaussians2D
    from tests.fixtures import surfel_sphere

    g = surfel_sphere(200)
    if kind == "far":
        return Gaussians2D(**{**g.__dict__, "means": g.means + 1e6})
    if kind == "huge":
        return Gaussians2D(**{**g.__dict__, "log_scales": g.log_scales + 12.0})
    if kind == "empty":
        return Gaussians2D(**{k: v[:0] for k, v in g.__dict__.items() if v is not None})
    return g


@pytest.mark.parametrize("kind,message", [("far", "not in the scene's frame"), ("huge", "median surfel size"),
                                          ("empty", "no surfels")])
def test_a_degenerate_asset_is_refused(micro_dataset, kind, message):
    from gspi.run.assets import AssetError, check_asset_covers_scene

    with pytest.raises(AssetError, match=message) as info:
        check_asset_covers_scene(_asset(kind), _test_scene(micro_dataset), "asset.ply")
    assert str(info.value).startswith("asset.ply: ")


def test_a_sound_asset_passes_and_is_measured(micro_dataset):
    from gspi.run.assets import check_asset_covers_scene

    info = check_asset_covers_scene(_asset("sound"), _test_scene(micro_dataset), "asset.ply")
    assert info["visible_fraction"] == 1.0 and info["median_scale"] < info["rig_radius"]


@pytest.mark.parametrize("kind", ["far", "empty"])
def test_gspi_run_fails_on_a_degenerate_user_asset(micro_dataset, tmp_path, kind):
    """Before: the run ended "complete" with black maps (far) or Stage I's misleading message."""
    from gspi.cli.run import main
    from gspi.gaussians.ply import write_ply
    from gspi.run.record import read_result

    ply = tmp_path / f"{kind}.ply"
    write_ply(ply, _asset(kind))
    out = tmp_path / "run"
    scene = _test_scene(micro_dataset).name
    code, text = run_cli(main, [f"data={micro_dataset}", f"out={out}", *TINY_RUN, "method=no_decomposition",
                                f"assets={ply}", f"scenes=[{scene}]", "figures=false"])
    assert_fails_naming(code, text, str(ply))
    record = read_result(out)
    assert record["status"] == "failed" and str(ply) in record["error"]


def test_black_predictions_fail_the_scene(workspace):
    from eval.common.layout import read_scene, write_material
    from gspi.run.assets import AssetError, check_prediction_covers_scene

    scene = read_scene(workspace / "gt" / "sphere_0")
    pred = workspace / "pred" / "sphere_0"
    assert check_prediction_covers_scene(scene, pred, "test") > 0.9
    for v in scene.split_views("test"):
        for channel in ("albedo", "roughness", "metallic"):
            write_material(pred / "test" / v.id, channel, torch.zeros(32, 32, 3 if channel == "albedo" else 1).numpy())
    with pytest.raises(AssetError, match="black on 100.0%") as info:
        check_prediction_covers_scene(scene, pred, "test")
    assert str(pred) in str(info.value)


def _ply_with_count(src, dst, count: int):
    raw = src.read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    lines = [f"element vertex {count}".encode() if line.startswith(b"element vertex") else line
             for line in head.split(b"\n")]
    dst.write_bytes(b"\n".join(lines) + b"end_header\n" + body)


def test_ply_header_declaring_fewer_vertices_is_refused(tmp_path):
    from gspi.gaussians.ply import PlyFormatError, read_ply, write_ply

    write_ply(tmp_path / "full.ply", _asset("sound"))
    _ply_with_count(tmp_path / "full.ply", tmp_path / "short.ply", 150)
    with pytest.raises(PlyFormatError, match=r"short.ply: .* after the 150 element\(s\)"):
        read_ply(tmp_path / "short.ply")
    assert read_ply(tmp_path / "full.ply").num_gaussians == 200  # the whole file still reads


def test_ply_with_overflowing_log_scales_is_refused(tmp_path):
    from gspi.gaussians.model import Gaussians2D
    from gspi.gaussians.ply import PlyFormatError, read_ply, write_ply

    g = _asset("sound")
    write_ply(tmp_path / "big.ply", Gaussians2D(**{**g.__dict__, "log_scales": g.log_scales + 100.0}))
    with pytest.raises(PlyFormatError, match="big.ply: scale of vertex .* overflows"):
        read_ply(tmp_path / "big.ply")


@pytest.mark.parametrize("content", [b"", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n"])
def test_ply_reader_cases_that_already_worked(tmp_path, content):
    """Kept as cases: an empty file or a truncated/incomplete one is named (handled before)."""
    from gspi.gaussians.ply import PlyFormatError, read_ply

    (tmp_path / "bad.ply").write_bytes(content)
    with pytest.raises(PlyFormatError, match="bad.ply: "):
        read_ply(tmp_path / "bad.ply")
