"""The evaluator on a fixture made by the tests: oracle, known errors, missing data, errors."""
import math
import shutil

import numpy as np
import pytest

from eval.evaluate import evaluate
from eval.common.layout import LayoutError, read_scene, write_material
from tests.fixtures import make_prediction, protocol


def test_scene_is_its_own_oracle(sphere_dataset, lpips_net):
    result = evaluate(sphere_dataset, sphere_dataset, protocol(), net=lpips_net)
    assert set(result.summary) == {"albedo", "roughness", "metallic", "relight"}
    for channel, m in result.summary.items():
        assert m["psnr"] == math.inf or m["psnr"] >= 60, channel
        assert m["ssim"] == pytest.approx(1.0, abs=1e-9)
        assert m["lpips"] == pytest.approx(0.0, abs=1e-6)
    # 2 scenes x 3 test views x (3 maps + 2 relight envs)
    assert len(result.rows) == 2 * 3 * 5
    assert result.info["missing"] == []


def test_known_roughness_error_gives_exact_psnr(sphere_dataset, tmp_path, lpips_net):
    offset = 6554 / 65535
    pred = make_prediction(sphere_dataset, tmp_path / "pred", roughness_offset=offset)
    result = evaluate(sphere_dataset, pred, protocol(**{"channels": ["roughness"]}), net=lpips_net)
    expected = -10 * math.log10(offset**2)
    for row in result.rows:
        assert row["psnr"] == pytest.approx(expected, abs=1e-6)
    assert result.info["method"] == "perturbed"
    assert result.info["runtime_min"] == {"material": 1.0, "end_to_end": 2.0}


def test_albedo_alignment_recovers_a_global_scale(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred", albedo_scale=0.6)
    raw = evaluate(sphere_dataset, pred, protocol(channels=["albedo"]), net=lpips_net)
    aligned = evaluate(sphere_dataset, pred, protocol(channels=["albedo"], albedo_alignment="scale"),
                       net=lpips_net)
    assert raw.summary["albedo"]["psnr"] < 25
    assert aligned.summary["albedo"]["psnr"] > 55  # only 16-bit quantisation remains


def test_missing_channel_is_absent_and_relit_with_fill(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred", channels=("albedo",))
    result = evaluate(sphere_dataset, pred, protocol(), net=lpips_net)
    assert set(result.summary) == {"albedo", "relight"}
    assert result.summary["relight"]["psnr"] < 60  # fills differ from the ground truth


def test_missing_view_is_reported(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred")
    shutil.rmtree(pred / "sphere_0" / "test" / "001")
    result = evaluate(sphere_dataset, pred, protocol(channels=["metallic"]), net=lpips_net)
    assert {"scene": "sphere_0", "view": "001", "channel": "metallic"} in result.info["missing"]
    assert len(result.rows) == 5
    with pytest.raises(LayoutError, match="missing prediction"):
        evaluate(sphere_dataset, pred, protocol(fail_on_missing_view=True), net=lpips_net)


def test_missing_scene_is_reported_not_silently_dropped(sphere_dataset, tmp_path, lpips_net):
    from eval.records.eval_folder import format_summary

    pred = make_prediction(sphere_dataset, tmp_path / "pred")
    full = evaluate(sphere_dataset, pred, protocol(channels=["roughness"]), net=lpips_net)
    assert full.info["missing_scenes"] == [] and "missing scenes" not in format_summary(full)
    shutil.rmtree(pred / "sphere_0")
    part = evaluate(sphere_dataset, pred, protocol(channels=["roughness"]), net=lpips_net)
    assert part.info["scenes"] == ["sphere_1"] and part.info["missing_scenes"] == ["sphere_0"]
    assert "missing scenes: 1 of the split(s)" in format_summary(part)
    # A single scene folder as the ground truth expects only that scene.
    one = evaluate(sphere_dataset / "sphere_1", pred, protocol(channels=["roughness"]), net=lpips_net)
    assert one.info["missing_scenes"] == []


def test_no_scene_present_is_an_error(sphere_dataset, tmp_path, lpips_net):
    (tmp_path / "empty" / "not_a_scene").mkdir(parents=True)
    with pytest.raises(LayoutError, match="no scene of the ground truth"):
        evaluate(sphere_dataset, tmp_path / "empty", protocol(), net=lpips_net)


def test_size_mismatch_names_the_file(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred")
    bad = pred / "sphere_1" / "test" / "002"
    write_material(bad, "metallic", np.zeros((20, 20)))
    with pytest.raises(LayoutError, match=r"sphere_1/test/002/metallic.png: size"):
        evaluate(sphere_dataset, pred, protocol(), net=lpips_net)


def test_missing_ground_truth_file_names_the_file(sphere_dataset, tmp_path, lpips_net):
    gt = tmp_path / "gt"
    shutil.copytree(sphere_dataset, gt)
    (gt / "sphere_0" / "test" / "000" / "normal.exr").unlink()
    with pytest.raises(LayoutError, match=r"sphere_0/test/000/normal.exr: file not found"):
        evaluate(gt, gt, protocol(), net=lpips_net)


def test_corrupt_png_names_the_file(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred")
    (pred / "sphere_0" / "test" / "000" / "albedo.png").write_bytes(b"not a png")
    with pytest.raises(LayoutError, match=r"albedo.png: not a readable PNG"):
        evaluate(sphere_dataset, pred, protocol(), net=lpips_net)


def test_grey_albedo_is_rejected(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred")
    write_material(pred / "sphere_0" / "test" / "000", "roughness", np.zeros((48, 48)))
    (pred / "sphere_0" / "test" / "000" / "roughness.png").rename(
        pred / "sphere_0" / "test" / "000" / "albedo.png")
    with pytest.raises(LayoutError, match=r"albedo.png: expected 3 channel"):
        evaluate(sphere_dataset, pred, protocol(), net=lpips_net)


def test_invalid_protocol_values_are_named():
    with pytest.raises(ValueError, match="albedo_alignment"):
        protocol(albedo_alignment="median")
    with pytest.raises(ValueError, match="channels"):
        protocol(channels=["albedo", "normal"])


def test_scene_json_errors_name_the_file(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "scene.json").write_text("{\"name\": \"s\"}")
    with pytest.raises(LayoutError, match=r"s/scene.json: missing key 'width'"):
        read_scene(tmp_path / "s")
    (tmp_path / "s" / "scene.json").write_text("{oops")
    with pytest.raises(LayoutError, match="invalid JSON"):
        read_scene(tmp_path / "s")


def test_exact_maps_hit_the_floor_and_are_counted_never_inf(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred", channels=("roughness", "metallic"))
    result = evaluate(sphere_dataset, pred, protocol(channels=["roughness", "metallic"]),
                      net=lpips_net)
    cap = 10 * math.log10(12 * 65535.0**2)
    assert result.summary["metallic"]["psnr"] == pytest.approx(cap)  # copied: MSE 0
    assert result.info["counts"]["metallic"] == {"images": 6, "psnr_floored": 6, "mae_iou": 6}
    assert result.info["counts"]["roughness"]["psnr_floored"] == 0
    assert "6 image(s) hit the PSNR floor" in result.info["note"]
    assert all(math.isfinite(r["psnr"]) for r in result.rows)


def test_metallic_mae_and_iou_on_scenes_with_metal(sphere_dataset, tmp_path, lpips_net):
    """The fixture's metal is x > 0.3; a prediction of metallic 0 everywhere has MAE = the
    metal fraction and IoU 0, while its PSNR/SSIM say little."""
    pred = make_prediction(sphere_dataset, tmp_path / "pred", channels=("metallic",))
    for scene in ("sphere_0", "sphere_1"):
        for view in ("000", "001", "002"):
            d = pred / scene / "test" / view
            write_material(d, "metallic", np.zeros_like(read_view_metallic(d)))
    result = evaluate(sphere_dataset, pred, protocol(channels=["metallic"]), net=lpips_net)
    gt = evaluate(sphere_dataset, sphere_dataset, protocol(channels=["metallic"]), net=lpips_net)
    for row, ref in zip(result.rows, gt.rows):
        assert ref["iou"] == 1.0 and ref["mae"] == 0.0
        # a view that shows metal: IoU 0; one that shows none: both metal sets empty, IoU 1
        assert row["iou"] == (0.0 if row["mae"] > 0 else 1.0) and row["mae"] < 1
    assert sum(r["mae"] > 0 for r in result.rows) >= 3
    # the metal-scene PSNR is the metallic PSNR of exactly those rows (every scene has metal here)
    assert all(r["psnr_metal"] == r["psnr"] for r in result.rows)
    assert result.summary["metallic"]["psnr_metal"] == pytest.approx(result.summary["metallic"]["psnr"])
    off = evaluate(sphere_dataset, pred, protocol(channels=["metallic"],
                                                  **{"metallic.extra_metrics": False}), net=lpips_net)
    assert "mae" not in off.summary["metallic"] and "psnr_metal" not in off.summary["metallic"]


def read_view_metallic(view_dir):
    from eval.common.layout import read_view_file
    return read_view_file(view_dir, "metallic.png")


def test_median_ratio_alignment_recovers_a_global_scale(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred", albedo_scale=0.6)
    aligned = evaluate(sphere_dataset, pred, protocol(channels=["albedo"],
                                                      albedo_alignment="median_ratio"), net=lpips_net)
    assert aligned.summary["albedo"]["psnr"] > 55  # only 16-bit quantisation remains


def test_mask_erosion_scores_fewer_pixels(sphere_dataset, tmp_path, lpips_net):
    pred = make_prediction(sphere_dataset, tmp_path / "pred", channels=("roughness",))
    offset = 6554 / 65535  # constant error: PSNR does not depend on how many pixels
    eroded = evaluate(sphere_dataset, pred, protocol(channels=["roughness"], mask_erosion_px=2),
                      net=lpips_net)
    assert eroded.rows[0]["psnr"] == pytest.approx(-10 * math.log10(offset**2), abs=1e-6)
    with pytest.raises(LayoutError, match="mask empty after eroding 1000 px"):
        evaluate(sphere_dataset, pred, protocol(channels=["roughness"], mask_erosion_px=1000),
                 net=lpips_net)


def test_a_network_other_than_the_protocols_is_refused(sphere_dataset, lpips_net):
    with pytest.raises(ValueError, match="eval.lpips.net='vgg'"):
        evaluate(sphere_dataset, sphere_dataset, protocol(**{"lpips.net": "vgg"}), net=lpips_net)


def test_device_auto_scores_like_cpu_here(sphere_dataset, tmp_path, lpips_net):
    """device=auto is the CPU here: the same rows, to the bit, as the default (the CPU path of
    before), with the device-touched steps on: lstsq alignment, relight fills, scale fit, erosion."""
    import torch

    from eval.common.device import resolve_device

    pred = make_prediction(sphere_dataset, tmp_path / "pred", albedo_scale=0.7, channels=("albedo", "roughness"))
    prot = protocol(albedo_alignment="lstsq", mask_erosion_px=1, **{"relight.scale_fit": "lstsq",
                                                                    "relight.psnr_hdr": True})
    before = evaluate(sphere_dataset, pred, prot, net=lpips_net)
    auto = evaluate(sphere_dataset, pred, prot, net=lpips_net, device=resolve_device("auto"))
    assert auto.rows == before.rows and auto.summary == before.summary
    assert auto.info["device"] == before.info["device"] == str(torch.device("cuda" if torch.cuda.is_available() else "cpu"))


def test_what_evaluate_reads_lands_on_the_requested_device(sphere_dataset):
    """Torch's meta device stands in for CUDA: a CPU tensor mixed into its arithmetic raises, so
    these pass only if the maps, the prefiltered environments and the protocol's constants are
    all made on the device asked for."""
    import torch

    from eval.scored_view import EnvironmentCache, load_pred_view as _load_pred_view
    from eval.metrics import erode_mask
    from eval.protocol import fit_albedo_scale

    meta = torch.device("meta")
    scene = read_scene(sphere_dataset / "sphere_0")
    pre = EnvironmentCache(meta).get(scene.envmap_path(scene.relight_envs[0]))
    assert {t.device for t in (pre.irradiance, pre.lut, *pre.specular)} == {meta}
    maps = _load_pred_view(scene.view_dir("test", "000"), (scene.height, scene.width), meta)
    assert set(maps) == {"albedo", "roughness", "metallic"} and {t.device for t in maps.values()} == {meta}
    mask = torch.ones(scene.height, scene.width, dtype=torch.bool, device=meta)
    assert erode_mask(mask, 2).device == meta
    assert fit_albedo_scale([maps["albedo"]], [maps["albedo"]], [mask], "none").device == meta


def test_the_record_names_the_bytes_it_scored(sphere_dataset, tmp_path, lpips_net):
    """eval_meta's checksums (next to the protocol hash): the oracle's prediction IS its ground
    truth, so both sides agree; one changed prediction pixel changes that side only."""
    from eval.checksums import scene_checksums

    oracle = evaluate(sphere_dataset, sphere_dataset, protocol(), net=lpips_net).info["checksums"]
    pred = make_prediction(sphere_dataset, tmp_path / "pred", roughness_offset=0.1)
    sums = evaluate(sphere_dataset, pred, protocol(**{"channels": ["roughness"]}), net=lpips_net).info["checksums"]
    assert oracle["per_scene"].keys() == sums["per_scene"].keys()
    for scene, pair in sums["per_scene"].items():
        assert pair == scene_checksums(sphere_dataset / scene, pred / scene, "test")
        assert pair["ground_truth"] == oracle["per_scene"][scene]["ground_truth"]
        assert pair["predictions"] != pair["ground_truth"]
    assert sums["ground_truth"] == oracle["ground_truth"] and sums["predictions"] != oracle["predictions"]
    assert len(sums["predictions"]) == 64


def test_peak_memory_is_the_largest_stage_peak():
    from eval.evaluate import peak_memory_mb

    metas = [{"stages": {"recon": {"seconds": 1, "peak_rss_mb": 600.0}, "stage2": {"peak_rss_mb": 950.5}}},
             {"stages": {"recon": {"peak_rss_mb": 700.0, "peak_cuda_mb": 12.0}}}, {}]
    assert peak_memory_mb(metas) == {"rss": 950.5, "cuda": 12.0}
    assert peak_memory_mb([{}, {"method": "imported"}]) == {}
