"""Protocol options and the field's presets (conf/eval/*.yaml), each on a hand-computed case.

Cases are tiny constant images whose scores have closed forms; the expected values are written
out from those formulas, never read back from the code under test.
"""
import math

import pytest
import torch

from eval.common.colorspace import linear_to_srgb, srgb_to_linear
from eval.common.conf import CONF_DIR
from eval.metrics import MSE_FLOOR_16BIT, erode_mask
from eval.protocol import display_relit, fit_albedo_scale
from eval.protocol_id import protocol_diff, protocol_dict, protocol_hash
from eval.scoring import score_pair, score_relit
from tests.fixtures import preset

PRESETS = ("default", "aligned_clamp", "stanford_orb", "tensoir", "gs_ir", "paper")
CAP = 10 * math.log10(1 / MSE_FLOOR_16BIT)


def square(size=32, lo=8, hi=24) -> torch.Tensor:
    mask = torch.zeros(size, size, dtype=torch.bool)
    mask[lo:hi, lo:hi] = True
    return mask


def const(value, size=32, channels=3) -> torch.Tensor:
    return torch.full((size, size, channels), float(value), dtype=torch.float64)


@pytest.fixture(scope="module")
def vgg():
    from eval.lpips.net import load_lpips
    return load_lpips("vgg")


class TestPresetsCompose:
    @pytest.mark.parametrize("name", PRESETS)
    def test_every_preset_composes_validates_and_has_its_own_hash(self, name):
        cfg = preset(name)
        others = {protocol_hash(protocol_dict(preset(o))) for o in PRESETS if o != name}
        assert protocol_hash(protocol_dict(cfg)) not in others

    def test_default_keeps_its_name_and_meaning(self):
        cfg = preset("default")
        assert (cfg.name, cfg.version, cfg.albedo_alignment, cfg.relight.tonemap) == \
            ("gspi-decoupled", 1, "none", "aces")
        assert (cfg.psnr.region, cfg.ssim.window, cfg.lpips.net, cfg.lpips.mode) == \
            ("mask", 11, "alex", "masked_mean")
        assert cfg.psnr.mse_floor == MSE_FLOOR_16BIT

    def test_an_override_keeps_the_name_but_changes_the_hash_and_diff(self):
        a, b = preset("default"), preset("default", "eval.relight.tonemap=clamp")
        assert a.name == b.name and protocol_hash(protocol_dict(a)) != protocol_hash(protocol_dict(b))
        assert protocol_diff(protocol_dict(a), protocol_dict(b)) == ["relight.tonemap: 'aces' != 'clamp'"]

    def test_the_per_channel_alias_is_the_same_protocol_as_lstsq(self):
        a = preset("default", "eval.albedo_alignment=per_channel")
        b = preset("default", "eval.albedo_alignment=lstsq")
        assert protocol_hash(protocol_dict(a)) == protocol_hash(protocol_dict(b))
        assert protocol_diff(protocol_dict(a), protocol_dict(b)) == []

    @pytest.mark.parametrize("key, value, allowed", [
        ("albedo_alignment", "mean", "none, scale, lstsq, per_channel, median_ratio"),
        ("albedo_space", "xyz", "srgb, linear"),
        ("psnr.region", "fg", "mask, image"),
        ("ssim.padding", "reflect", "valid, same"),
        ("lpips.net", "squeeze", "alex, vgg"),
        ("lpips.mode", "mean", "masked_mean, composite"),
        ("relight.tonemap", "filmic", "aces, clamp, reinhard, none"),
        ("relight.scale_fit", "median", "none, lstsq"),
    ])
    def test_a_typo_lists_the_allowed_values(self, key, value, allowed):
        with pytest.raises(ValueError, match=f"eval.{key}='{value}'; allowed: {allowed}"):
            preset("default", f"eval.{key}={value}")

    @pytest.mark.parametrize("override, message", [
        ("eval.psnr.mse_floor=0", "must be > 0"), ("eval.ssim.window=4", "odd"),
        ("eval.mask_erosion_px=-1", ">= 0")])
    def test_bad_numbers_are_refused(self, override, message):
        with pytest.raises(ValueError, match=message):
            preset("default", override)


class TestOptions:
    def test_albedo_space_linear_scores_decoded_values(self, lpips_net):
        cfg = preset("default", "eval.albedo_space=linear")
        from eval.scoring import score_map
        mask = square()
        row = score_map("albedo", const(0.5), const(0.6), mask, cfg, lpips_net)
        d = float(srgb_to_linear(torch.tensor(0.6, dtype=torch.float64)) - srgb_to_linear(torch.tensor(0.5, dtype=torch.float64)))
        assert row["psnr"] == pytest.approx(-10 * math.log10(d * d), abs=1e-6)
        srgb = score_map("albedo", const(0.5), const(0.6), mask, preset("default"), lpips_net)
        assert srgb["psnr"] == pytest.approx(20.0, abs=1e-9)

    def test_alignment_modes_and_the_per_channel_alias(self):
        # linear pred 0.2, 0.4 ; gt 0.3, 0.5 (one channel shown, all three equal)
        p = [linear_to_srgb(torch.tensor([0.2, 0.4]).double()[:, None, None].expand(2, 1, 3))]
        g = [linear_to_srgb(torch.tensor([0.3, 0.5]).double()[:, None, None].expand(2, 1, 3))]
        m = [torch.ones(2, 1, dtype=torch.bool)]
        lstsq = (0.2 * 0.3 + 0.4 * 0.5) / (0.2**2 + 0.4**2)          # 1.3
        median = min(0.3 / 0.2, 0.5 / 0.4)                            # lower middle: 1.25
        assert fit_albedo_scale(p, g, m, "lstsq") == pytest.approx(torch.full((3,), lstsq).double())
        assert torch.equal(fit_albedo_scale(p, g, m, "per_channel"), fit_albedo_scale(p, g, m, "lstsq"))
        assert fit_albedo_scale(p, g, m, "median_ratio") == pytest.approx(
            torch.full((3,), median).double(), abs=1e-6)
        assert torch.equal(fit_albedo_scale(p, g, m, "none"), torch.ones(3).double())

    def test_median_ratio_is_robust_to_an_outlier(self):
        pred = torch.tensor([0.1, 0.1, 0.1, 0.1, 0.1]).double()
        gt = torch.tensor([0.2, 0.2, 0.2, 0.3, 1.0]).double()   # ratios 2, 2, 2, 3, 10
        p = [linear_to_srgb(pred[:, None, None].expand(5, 1, 3))]
        g = [linear_to_srgb(gt[:, None, None].expand(5, 1, 3))]
        s = fit_albedo_scale(p, g, [torch.ones(5, 1, dtype=torch.bool)], "median_ratio")
        assert s == pytest.approx(torch.full((3,), 2.0).double(), abs=1e-5)

    def test_tonemap_none_keeps_linear_values_up_to_hdr_max(self):
        cfg = preset("default", "eval.relight.tonemap=none", "eval.relight.hdr_max=2.0")
        x = torch.tensor([-1.0, 0.5, 1.5, 3.0]).double()
        assert torch.equal(display_relit(x, cfg.relight), torch.tensor([0.0, 0.5, 1.5, 2.0]).double())

    def test_lpips_unnormalised_inputs_are_fed_as_0_1(self, lpips_net):
        a, b = const(0.3), const(0.3)
        b[8:24, 8:16] = 0.9
        mask = torch.ones(32, 32, dtype=torch.bool)
        cfg = preset("default", "eval.lpips.normalize=false", "eval.lpips.mode=composite")
        got = score_pair(a, b, mask, cfg, lpips_net)["lpips"]
        x, y = (t.float().permute(2, 0, 1)[None] for t in (a, b))
        with torch.no_grad():
            assert got == pytest.approx(float(lpips_net(x, y)), abs=1e-7)
        assert got != pytest.approx(score_pair(a, b, mask, preset("default", "eval.lpips.mode=composite"),
                                               lpips_net)["lpips"], abs=1e-4)


class TestStanfordOrb:
    """32x32 images, a 16x16 mask eroded by 2 px to 12x12 = 144 pixels."""

    def test_albedo_psnr_whole_image_with_grey_floor(self, vgg):
        cfg = preset("stanford_orb")
        mask = erode_mask(square(), cfg.mask_erosion_px)
        assert int(mask.sum()) == 144
        # 0.65 vs 0.6: MSE 144 * 0.05^2 / 1024 -> 34.540 dB; grey: 144 * 0.1^2 / 1024 -> 28.519 dB
        near = score_pair(const(0.65), const(0.6), mask, cfg, vgg)
        assert near["psnr"] == pytest.approx(10 * math.log10(1024 / (144 * 0.0025)), abs=1e-9)
        # 0.9 vs 0.6: 18.977 dB is below the grey floor, which is reported instead
        far = score_pair(const(0.9), const(0.6), mask, cfg, vgg)
        assert far["psnr"] == pytest.approx(10 * math.log10(1024 / (144 * 0.01)), abs=1e-9)

    def test_relight_scale_fit_psnr_l_and_psnr_h(self, vgg):
        cfg = preset("stanford_orb")
        mask = erode_mask(square(), cfg.mask_erosion_px)
        ref = torch.zeros(32, 32, 3, dtype=torch.float64)
        ref[6:26, 6:16], ref[6:26, 16:26] = 0.25, 1.0   # scored: 72 px at 0.25, 72 at 1.0
        out = torch.where(mask[..., None], torch.full_like(ref, 0.5), torch.zeros_like(ref))
        row = score_relit(out, ref, mask, cfg, vgg)
        s = (0.25 * 0.5 + 1.0 * 0.5) / (2 * 0.5**2)            # lstsq scale 1.25 -> 0.625
        srgb = lambda v: float(linear_to_srgb(torch.tensor(v, dtype=torch.float64)))  # noqa: E731
        mse_l = 72 * ((srgb(0.625) - srgb(0.25)) ** 2 + (srgb(0.625) - 1.0) ** 2) / 1024
        grey_l = 72 * ((0.5 - srgb(0.25)) ** 2 + (0.5 - 1.0) ** 2) / 1024
        assert row["psnr"] == pytest.approx(-10 * math.log10(min(mse_l, grey_l)), abs=1e-9)
        k = (srgb(0.25) + 1.0) / (0.25 + 1.0)                   # GT renormalisation
        mse_h = 144 * (0.375 * k) ** 2 / 1024
        grey_h = 72 * ((0.5 - 0.25 * k) ** 2 + (0.5 - k) ** 2) / 1024
        assert s == 1.25 and 1.0 * k < 4.0                       # nothing clipped at hdr_max
        assert row["psnr_h"] == pytest.approx(-10 * math.log10(min(mse_h, grey_h)), abs=1e-9)


class TestTensoirAndGsIr:
    def test_tensoir_psnr_over_the_full_image_on_white(self, vgg):
        cfg = preset("tensoir")
        mask = square()
        # 0.1 error on 256 of 1024 pixels: MSE 0.0025 -> 26.0206 dB
        row = score_pair(const(0.5), const(0.6), mask, cfg, vgg)
        assert row["psnr"] == pytest.approx(10 * math.log10(400), abs=1e-9)
        assert cfg.background == 1.0 and cfg.albedo_alignment == "median_ratio"

    def test_gs_ir_lpips_on_unnormalised_vgg_inputs(self, vgg):
        cfg = preset("gs_ir")
        a, b = const(0.2), const(0.2)
        b[8:24, 8:24] = 0.7
        mask = torch.ones(32, 32, dtype=torch.bool)
        x, y = (t.float().permute(2, 0, 1)[None] for t in (a, b))
        with torch.no_grad():
            want = float(vgg(x, y))  # lpips(img, gt) on [0, 1] inputs, as relight_eval.py
        assert score_pair(a, b, mask, cfg, vgg)["lpips"] == pytest.approx(want, abs=1e-7)

    def test_exact_prediction_scores_the_cap_under_every_preset(self, vgg, lpips_net):
        for name in PRESETS:
            cfg = preset(name)
            net = vgg if cfg.lpips.net == "vgg" else lpips_net
            mask = erode_mask(square(), cfg.mask_erosion_px)
            gt = const(0.4)
            # exact = the GT as scored; where the prediction is not masked (gs_ir) that includes
            # the background outside the mask
            pred = gt if cfg.mask_prediction else torch.where(mask[..., None], gt, torch.full_like(gt, cfg.background))
            row = score_pair(pred, gt, mask, cfg, net)
            assert row["psnr"] == pytest.approx(CAP) and row["psnr_floored"], name


class TestPaper:
    def test_paper_is_masked_psnr_and_full_image_vgg_lpips_on_black(self, vgg):
        cfg = preset("paper")
        mask = square()
        a, b = const(0.5), const(0.6)
        row = score_pair(a, b, mask, cfg, vgg)
        assert row["psnr"] == pytest.approx(20.0, abs=1e-9)   # in the mask, as the default
        inside = mask[..., None]
        x, y = (torch.where(inside, t, torch.zeros_like(t)).float().permute(2, 0, 1)[None] * 2 - 1
                for t in (a, b))
        with torch.no_grad():
            assert row["lpips"] == pytest.approx(float(vgg(x, y)), abs=1e-7)


def test_protocol_dataclass_equals_default_yaml():
    """ProtocolConfig() (what code that builds a protocol gets) is conf/eval/default.yaml,
    key for key: the yaml is read as plain data, without the dataclass as its schema."""
    import dataclasses

    import yaml

    from eval.config import ProtocolConfig

    from pathlib import Path

    own = yaml.safe_load((Path(CONF_DIR) / "eval" / "default.yaml").read_text())
    own.pop("defaults")
    assert own == dataclasses.asdict(ProtocolConfig())
