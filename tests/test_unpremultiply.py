"""`eval.unpremultiply`: maps divided by the method's own alpha.png inside the GT mask."""
import math

import numpy as np
import pytest
import torch

from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.evaluate import evaluate
from eval.common.layout import read_scene, read_view_file, write_material, write_view_file
from eval.protocol_id import describe_protocol, protocol_dict, protocol_hash
from eval.unpremultiply import unpremultiply
from tests.fixtures import make_prediction, protocol


def test_hand_computed_pixels():
    """2x2 pixels: (0,0) alpha 0.5, (0,1) alpha 0.25 (x4 overshoots: clamped to 1), (1,0) alpha 0
    (left), (1,1) outside the mask (left)."""
    mask = torch.tensor([[True, True], [True, False]])
    alpha = torch.tensor([[0.5, 0.25], [0.0, 0.5]])
    lin = torch.tensor([[[0.2, 0.1, 0.05], [0.3, 0.3, 0.3]], [[0.2, 0.2, 0.2], [0.2, 0.2, 0.2]]],
                       dtype=torch.float64)
    rough = torch.tensor([[[0.3], [0.2]], [[0.3], [0.3]]], dtype=torch.float64)
    out = unpremultiply({"albedo": linear_to_srgb(lin), "roughness": rough}, alpha, mask)
    got = srgb_to_linear(out["albedo"])
    torch.testing.assert_close(got[0, 0], torch.tensor([0.4, 0.2, 0.1], dtype=torch.float64))
    torch.testing.assert_close(got[0, 1], torch.tensor([1.0, 1.0, 1.0], dtype=torch.float64))
    torch.testing.assert_close(got[1], lin[1])
    torch.testing.assert_close(out["roughness"][..., 0],
                               torch.tensor([[0.6, 0.8], [0.3, 0.3]], dtype=torch.float64))


def test_premultiplied_roughness_is_recovered(sphere_dataset, tmp_path, lpips_net):
    """Roughness saved as gt x 0.6 inside the mask with alpha.png = 0.6 (39321/65535, exact in
    16 bits): unpremultiplied, only the 16-bit rounding of the stored product remains."""
    a = 39321 / 65535
    pred = make_prediction(sphere_dataset, tmp_path / "pred", channels=("roughness",))
    want_raw, want_div = [], []
    for scene_dir in sorted(sphere_dataset.glob("*/scene.json")):
        scene = read_scene(scene_dir.parent)
        for v in scene.split_views("test"):
            gdir, pdir = scene.view_dir("test", v.id), pred / scene.name / "test" / v.id
            gt = read_view_file(gdir, "roughness.png").astype(np.float64)
            mask = read_view_file(gdir, "mask.png")[..., 0] > 0.5
            write_material(pdir, "roughness", np.where(mask[..., None], gt * a, gt))
            write_view_file(pdir, "alpha.png", np.full(gt.shape, a))
            stored = read_view_file(pdir, "roughness.png").astype(np.float64)[mask]
            want_raw.append(-10 * math.log10(np.mean((stored - gt[mask]) ** 2)))
            a_read = read_view_file(pdir, "alpha.png").astype(np.float64)[mask]  # as read (float32)
            mse = np.mean((np.clip(stored / a_read, 0, 1) - gt[mask]) ** 2)
            want_div.append(-10 * math.log10(max(mse, 1.9403145770321738e-11)))
    raw = evaluate(sphere_dataset, pred, protocol(channels=["roughness"]), net=lpips_net)
    div = evaluate(sphere_dataset, pred, protocol(channels=["roughness"], unpremultiply=True), net=lpips_net)
    assert [r["psnr"] for r in raw.rows] == pytest.approx(want_raw, abs=1e-6)
    assert [r["psnr"] for r in div.rows] == pytest.approx(want_div, abs=1e-6)
    assert min(want_div) > 90 > max(want_raw)
    assert div.info["unpremultiplied_views"] == 6 and "unpremultiplied_views" not in raw.info
    assert protocol_hash(protocol_dict(protocol(unpremultiply=True))) != protocol_hash(protocol_dict(protocol()))
    # false is what every evaluation did before the key existed: those records hash alike
    before = {k: v for k, v in protocol_dict(protocol()).items() if k != "unpremultiply"}
    assert protocol_hash(before) == protocol_hash(protocol_dict(protocol()))
    assert "un-premultiplied" in describe_protocol(protocol_dict(protocol(unpremultiply=True)))
    assert "un-premultiplied" not in describe_protocol(protocol_dict(protocol()))


def test_unpremultiply_must_be_a_boolean():
    with pytest.raises(Exception, match="unpremultiply"):
        protocol(unpremultiply="sometimes")
