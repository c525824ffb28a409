"""Masked PSNR / SSIM / LPIPS: golden values, invariants and error messages."""
import math

import pytest
import torch
from skimage.metrics import structural_similarity

from eval.metrics import (MSE_FLOOR_16BIT, erode_mask, grey_psnr, masked_iou, masked_lpips,
                          masked_mae, masked_mse, masked_psnr, masked_ssim, psnr_from_mse)


def _pair(shape=(48, 40, 3), seed=0, noise=0.1):
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(*shape, generator=g)
    pred = (gt + noise * torch.randn(*shape, generator=g)).clamp(0, 1)
    return pred, gt


class TestMaskedPsnr:
    def test_identical_scores_the_16bit_cap_never_inf(self):
        x = torch.rand(8, 8, 3)
        # (1/65535)^2 / 12 -> 10 log10(12 * 65535^2) = 107.1213 dB
        assert MSE_FLOOR_16BIT == pytest.approx(1 / (12 * 65535.0**2), rel=1e-15)
        assert masked_psnr(x, x, torch.ones(8, 8)) == pytest.approx(107.12127853578, abs=1e-9)
        assert psnr_from_mse(0.0) == masked_psnr(x, x, torch.ones(8, 8))

    def test_floor_binds_only_below_it(self):
        assert psnr_from_mse(1e-4) == pytest.approx(40.0, abs=1e-12)
        assert psnr_from_mse(1e-12, mse_floor=1e-10) == pytest.approx(100.0, abs=1e-12)
        with pytest.raises(ValueError, match="mse_floor"):
            psnr_from_mse(0.0, mse_floor=0.0)

    def test_region_image_divides_by_all_pixels(self):
        # 10x10, top half masked with error 0.1: masked MSE 0.01 (20 dB); whole-image MSE of the
        # mask-multiplied images 0.005 (23.0103 dB); errors outside the mask are zeroed.
        gt = torch.zeros(10, 10, 1, dtype=torch.float64)
        pred = torch.full((10, 10, 1), 0.1, dtype=torch.float64)
        mask = torch.zeros(10, 10, dtype=torch.bool)
        mask[:5] = True
        assert masked_mse(pred, gt, mask, region="image") == pytest.approx(0.005)
        assert masked_psnr(pred, gt, mask, region="image") == pytest.approx(10 * math.log10(200))
        with pytest.raises(ValueError, match="allowed: mask, image"):
            masked_psnr(pred, gt, mask, region="masked")

    def test_grey_floor_is_psnr_of_constant_half(self):
        gt = torch.full((4, 4, 3), 0.6, dtype=torch.float64)
        assert grey_psnr(gt, torch.ones(4, 4)) == pytest.approx(20.0, abs=1e-9)

    def test_hand_computed_20db(self):
        pred = torch.full((8, 8, 1), 0.5, dtype=torch.float64)
        gt = torch.full((8, 8, 1), 0.6, dtype=torch.float64)
        assert masked_psnr(pred, gt, torch.ones(8, 8)) == pytest.approx(20.0, abs=1e-9)

    def test_mse_over_masked_pixels_only(self):
        gt = torch.zeros(10, 10, 1, dtype=torch.float64)
        pred = gt.clone()
        pred[:5] = 0.1  # error only in the top half
        mask = torch.zeros(10, 10, dtype=torch.bool)
        mask[:5] = True
        assert masked_psnr(pred, gt, mask) == pytest.approx(20.0, abs=1e-9)
        assert masked_psnr(pred, gt, torch.ones(10, 10)) == pytest.approx(10 * math.log10(1 / 0.005))

    def test_outside_mask_cannot_change_result(self):
        pred, gt = _pair()
        mask = torch.zeros(48, 40, dtype=torch.bool)
        mask[10:30, 5:35] = True
        other = pred.clone()
        other[~mask] = torch.rand(int((~mask).sum()), 3)
        assert masked_psnr(pred, gt, mask) == masked_psnr(other, gt, mask)

    @pytest.mark.parametrize("bad, message", [
        (lambda p: p.fill_(float("nan")), "NaN/Inf"),
        (lambda p: p.__setitem__((0, 0, 0), float("inf")), "NaN/Inf"),
    ])
    def test_nan_inf_rejected(self, bad, message):
        pred, gt = _pair()
        bad(pred)
        with pytest.raises(ValueError, match=message):
            masked_psnr(pred, gt, torch.ones(48, 40))

    def test_empty_mask_and_shape_errors(self):
        pred, gt = _pair()
        with pytest.raises(ValueError, match="mask is empty"):
            masked_psnr(pred, gt, torch.zeros(48, 40))
        with pytest.raises(ValueError, match="shape"):
            masked_psnr(pred[:, :30], gt, torch.ones(48, 40))
        with pytest.raises(ValueError, match="mask shape"):
            masked_psnr(pred, gt, torch.ones(40, 48))


class TestErodeMask:
    def test_radius_two_is_a_5x5_kernel_and_the_border_does_not_erode(self):
        mask = torch.zeros(9, 9, dtype=torch.bool)
        mask[1:8, 1:8] = True        # 7x7 square -> a 3x3 core after a 5x5 erosion
        eroded = erode_mask(mask, 2)
        assert eroded.sum() == 9 and eroded[3:6, 3:6].all()
        assert erode_mask(torch.ones(6, 6), 2).all()  # cv2.erode's default border
        assert torch.equal(erode_mask(mask, 0), mask)
        with pytest.raises(ValueError, match=">= 0"):
            erode_mask(mask, -1)


    @pytest.mark.parametrize("radius", [1, 2, 3, 7, 40, 1000])
    def test_equals_kornias_square_erosion_on_random_masks(self, radius):
        """The separable max-pool erosion is kornia.morphology.erosion with the full square kernel
        (the implementation before session 12), border included; a radius beyond the image too."""
        import kornia

        gen = torch.Generator().manual_seed(radius)
        for shape in ((17, 23), (40, 31)):
            mask = torch.rand(shape, generator=gen) > 0.15
            mask[: shape[0] // 2] = True  # a large solid part, so wide radii keep something
            r = min(radius, 45)  # kornia's full kernel at r = 1000 is the slow case being replaced
            kernel = torch.ones(2 * r + 1, 2 * r + 1, dtype=torch.float64)
            want = kornia.morphology.erosion(mask.double()[None, None], kernel)[0, 0] > 0.5
            assert torch.equal(erode_mask(mask, radius), want), (radius, shape)
            assert torch.equal(erode_mask(mask.double(), radius), want)

class TestMetallicExtras:
    def test_mae_and_iou_by_hand(self):
        gt = torch.zeros(2, 4, 1, dtype=torch.float64)
        gt[:, :2] = 1.0                       # metal: 4 pixels
        pred = torch.zeros(2, 4, 1, dtype=torch.float64)
        pred[:, 1:3] = 0.8                    # predicted metal: 4 pixels, 2 shared
        mask = torch.ones(2, 4)
        # |err|: col0 1, col1 0.2, col2 0.8, col3 0 -> mean 0.5; IoU 2 / 6
        assert masked_mae(pred, gt, mask) == pytest.approx(0.5)
        assert masked_iou(pred, gt, mask) == pytest.approx(1 / 3)
        assert masked_iou(pred * 0, gt * 0, mask) == 1.0


class TestMaskedSsim:
    @pytest.mark.parametrize("shape", [(48, 40, 3), (33, 57, 1), (64, 64, 3)])
    def test_matches_scikit_image_with_full_mask(self, shape):
        pred, gt = _pair(shape, seed=shape[0])
        ref = structural_similarity(pred.numpy(), gt.numpy(), gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False, data_range=1, channel_axis=-1)
        assert masked_ssim(pred, gt, torch.ones(shape[:2])) == pytest.approx(ref, abs=1e-6)

    def test_identical_is_one(self):
        x = torch.rand(32, 32, 3)
        mask = torch.zeros(32, 32)
        mask[8:20, 8:24] = 1
        assert masked_ssim(x, x, mask) == pytest.approx(1.0, abs=1e-12)

    def test_outside_mask_cannot_change_result(self):
        pred, gt = _pair()
        mask = torch.zeros(48, 40, dtype=torch.bool)
        mask[12:36, 8:30] = True
        noisy_pred, noisy_gt = pred.clone(), gt.clone()
        noisy_pred[~mask], noisy_gt[~mask] = 1.0, 0.0
        assert masked_ssim(pred, gt, mask) == pytest.approx(masked_ssim(noisy_pred, noisy_gt, mask),
                                                           abs=1e-12)

    def test_mask_on_border_only_is_an_error(self):
        pred, gt = _pair()
        mask = torch.zeros(48, 40, dtype=torch.bool)
        mask[:3] = True
        with pytest.raises(ValueError, match="border"):
            masked_ssim(pred, gt, mask)

    def test_constant_images_by_hand_any_window(self):
        # variances 0: SSIM = (2ab + C1) / (a^2 + b^2 + C1), C1 = 0.01^2
        a = torch.full((16, 16, 1), 0.5, dtype=torch.float64)
        b = torch.full((16, 16, 1), 0.6, dtype=torch.float64)
        for window in (3, 11):
            assert masked_ssim(a, b, torch.ones(16, 16), window=window) == pytest.approx(
                0.6001 / 0.6101, abs=1e-12)
        with pytest.raises(ValueError, match="odd"):
            masked_ssim(a, b, torch.ones(16, 16), window=4)

    def test_region_image_is_stanford_orbs_kornia_ssim_loss(self):
        import kornia

        pred, gt = _pair()
        mask = torch.zeros(48, 40, dtype=torch.bool)
        mask[6:40, 4:30] = True
        m = mask[..., None].double()
        x, y = ((t.double() * m).permute(2, 0, 1)[None] for t in (pred, gt))
        reference = 1 - 2 * float(kornia.losses.ssim_loss(x, y, 3))  # orb/utils/test.py:ssim
        assert masked_ssim(pred, gt, mask, window=3, region="image", padding="same") == pytest.approx(
            reference, abs=1e-12)

    def test_worse_prediction_scores_lower(self):
        _, gt = _pair()
        small, _ = _pair(noise=0.05)
        large, _ = _pair(noise=0.3)
        m = torch.ones(48, 40)
        assert masked_ssim(small, gt, m) > masked_ssim(large, gt, m)


class TestMaskedLpips:
    def test_identical_is_zero(self, lpips_net):
        x = torch.rand(48, 48, 3)
        assert masked_lpips(x, x, torch.ones(48, 48), net=lpips_net) == pytest.approx(0.0, abs=1e-7)

    def test_grey_maps_are_replicated(self, lpips_net):
        pred, gt = _pair((48, 48, 1))
        grey = masked_lpips(pred, gt, torch.ones(48, 48), net=lpips_net, mode="composite")
        rgb = masked_lpips(pred.expand(-1, -1, 3), gt.expand(-1, -1, 3), torch.ones(48, 48),
                           net=lpips_net, mode="composite")
        assert grey == pytest.approx(rgb, abs=1e-6) and grey > 0

    def test_outside_mask_cannot_change_result(self, lpips_net):
        pred, gt = _pair((48, 48, 3))
        mask = torch.zeros(48, 48, dtype=torch.bool)
        mask[8:40, 10:38] = True
        other = pred.clone()
        other[~mask] = 0.77
        for mode in ("masked_mean", "composite"):
            a = masked_lpips(pred, gt, mask, net=lpips_net, mode=mode)
            b = masked_lpips(other, gt, mask, net=lpips_net, mode=mode)
            assert a == pytest.approx(b, abs=1e-7)

    def test_masked_mean_differs_from_composite_for_small_objects(self, lpips_net):
        pred, gt = _pair((64, 64, 3), noise=0.2)
        mask = torch.zeros(64, 64, dtype=torch.bool)
        mask[24:40, 24:40] = True
        inside = masked_lpips(pred, gt, mask, net=lpips_net, mode="masked_mean")
        diluted = masked_lpips(pred, gt, mask, net=lpips_net, mode="composite")
        assert inside > diluted > 0

    def test_bad_mode_and_small_image(self, lpips_net):
        pred, gt = _pair((48, 48, 3))
        with pytest.raises(ValueError, match="allowed"):
            masked_lpips(pred, gt, torch.ones(48, 48), net=lpips_net, mode="bogus")
        with pytest.raises(ValueError, match="too small"):
            masked_lpips(pred[:16, :16], gt[:16, :16], torch.ones(16, 16), net=lpips_net)


def test_valid_ssim_map_is_kornias_in_float64_and_unchanged_in_float32():
    """ssim_map's separable-conv form (kept so Stage III's float32 loss, hence the demo, is
    unchanged) is kornia.metrics.ssim with valid padding to 1e-12 in float64."""
    import kornia

    from eval.metrics import ssim_map

    g = torch.Generator().manual_seed(3)
    a, b = torch.rand(2, 40, 36, 3, generator=g, dtype=torch.float64)
    ref = kornia.metrics.ssim(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None], 11, eps=0.0,
                              padding="valid")[0].permute(1, 2, 0)
    ours = ssim_map(a, b)
    assert ours.shape == (30, 26, 3)
    assert float((ours - ref).abs().max()) < 1e-12
    assert ssim_map(a.float(), b.float()).dtype == torch.float32
