"""Tests of gspi.stage2.schedule and gspi.stage2.sampler (closed-form models; diffusers as oracle via tests/golden/diffusers_ddim.json)."""
import json
from pathlib import Path

import pytest
import torch

from gspi.stage2.model import DenoiserOutput
from gspi.stage2.sampler import ddim_sample
from gspi.stage2.schedule import (cosine_alphas_cumprod, ddim_timesteps, eps_from_f0, f0_from_eps, min_snr_eps_weights,
                                  predict_eps_from_f0, predict_f0_from_eps, q_sample, snr)
from tests.oracle_fixtures import (FULL_LOOP_CASES, NUM_STEPS_CASES, AffineEpsModel, add_noise_inputs,
                                   make_f0, make_inputs)


class OracleEpsModel(torch.nn.Module):
    """Predicts the exact noise that maps the known f0 to f_t (diffusers test_full_loop_no_noise)."""

    def __init__(self, f0, alphas_cumprod):
        super().__init__()
        self.f0, self.alphas_cumprod, self.calls = f0, alphas_cumprod, []

    def forward(self, f_t, t, inputs, *, prev_latents=None, cond_keep=None, write_chunk=None):
        self.calls.append((int(t[0]), prev_latents))
        eps = predict_eps_from_f0(f_t, t, self.f0, alphas_cumprod=self.alphas_cumprod)
        return DenoiserOutput(eps=eps, latents=torch.full((f_t.shape[0], 3, 4), float(t[0])))


class TestCosineSchedule:
    def test_values_match_method_notes(self):
        ab = cosine_alphas_cumprod(1000)
        assert ab.shape == (1000,) and ab.dtype == torch.float64
        assert 1 - ab[0].item() == pytest.approx(4e-5, rel=0.05)
        assert ab[100].item() == pytest.approx(0.972, abs=5e-4)
        assert ab[500].item() == pytest.approx(0.492, abs=5e-4)
        assert ab[900].item() == pytest.approx(0.0236, abs=5e-5)
        assert ab[999].item() == pytest.approx(2.4e-9, rel=0.02)
        assert torch.all(ab[1:] < ab[:-1])

    def test_trailing_timesteps(self):
        steps = ddim_timesteps(50)
        assert steps[0] == 999 and steps[-1] == 19 and len(steps) == 50
        assert torch.all(steps[:-1] - steps[1:] == 20)
        with pytest.raises(ValueError):
            ddim_timesteps(0)


class TestMinSnr:
    def test_weights(self):
        t = torch.arange(1000)
        s, w = snr(t), min_snr_eps_weights(t, gamma=5.0)
        low = s < 5
        assert torch.all(w[low] == 1)
        torch.testing.assert_close(w[~low], (5.0 / s[~low]).float())
        assert w.dtype == torch.float32 and low.nonzero().min() == 261
        assert w[0].item() == pytest.approx(2.06e-4, rel=0.01)

    def test_floor_keeps_x0_weight(self):
        # x0-space weight = eps weight * SNR: Min-SNR gives min(SNR, 5), the floor max(., 1)
        t = torch.arange(1000)
        s = snr(t)
        plain, floored = min_snr_eps_weights(t, gamma=5.0), min_snr_eps_weights(t, gamma=5.0, floor=1.0)
        x0_weight = (floored.double() * s)
        torch.testing.assert_close(x0_weight, s.clamp(1.0, 5.0), rtol=1e-6, atol=0)
        above = s >= 1
        assert torch.equal(plain[above], floored[above]) and above.nonzero().max() == 495
        assert floored[999].item() > 1e6 * plain[999].item()
        assert torch.equal(min_snr_eps_weights(t, gamma=5.0, floor=0.0), plain)
        with pytest.raises(ValueError, match="floor 6.0"):
            min_snr_eps_weights(t, gamma=5.0, floor=6.0)


class TestQSample:
    def test_round_trip(self):
        f0 = make_f0()
        eps = torch.randn(f0.shape, generator=torch.Generator().manual_seed(1), dtype=f0.dtype)
        t = torch.tensor([3, 870])
        f_t = q_sample(f0, t, eps)
        torch.testing.assert_close(predict_f0_from_eps(f_t, t, eps), f0, rtol=0, atol=1e-9)
        torch.testing.assert_close(predict_eps_from_f0(f_t, t, f0), eps, rtol=0, atol=1e-9)

    def test_conversions_take_a_float_or_a_tensor_alpha_bar(self):
        f0, eps = make_f0(), make_f0(seed=4)
        ab = float(cosine_alphas_cumprod()[700])
        f_t = q_sample(f0, 700, eps)
        torch.testing.assert_close(f0_from_eps(f_t, eps, ab), f0, rtol=0, atol=1e-9)
        torch.testing.assert_close(eps_from_f0(f_t, f0, torch.tensor(ab, dtype=f0.dtype)), eps, rtol=0, atol=1e-9)
        assert not torch.allclose(f0_from_eps(f_t, eps, ab * 0.99), f0, atol=1e-3)

    def test_per_sample_timesteps(self):
        f0, eps = make_f0(), torch.zeros(2, 16, 5, dtype=torch.float64)
        ab = cosine_alphas_cumprod()
        f_t = q_sample(f0, torch.tensor([0, 500]), eps)
        torch.testing.assert_close(f_t[1], ab[500].sqrt() * f0[1])


class TestDdimSample:
    def test_oracle_model_recovers_f0(self):
        f0 = make_f0()
        ab = cosine_alphas_cumprod()
        model = OracleEpsModel(f0, ab)
        noise = torch.randn(f0.shape, generator=torch.Generator().manual_seed(2), dtype=f0.dtype)
        out = ddim_sample(model, make_inputs(f0), num_steps=10, noise=noise, self_condition=True)
        torch.testing.assert_close(out, f0, rtol=0, atol=1e-9)
        assert [c[0] for c in model.calls] == ddim_timesteps(10).tolist()
        assert model.calls[0][1] is None  # self-conditioning: zeros first, then the previous latents
        assert all(float(c[1][0, 0, 0]) == prev[0] for c, prev in zip(model.calls[1:], model.calls))

    def test_deterministic_with_generator(self):
        f0 = make_f0().float()
        model = AffineEpsModel()
        a = ddim_sample(model, make_inputs(f0), 5, torch.Generator().manual_seed(7), eta=0.5)
        b = ddim_sample(model, make_inputs(f0), 5, torch.Generator().manual_seed(7), eta=0.5)
        c = ddim_sample(model, make_inputs(f0), 5, torch.Generator().manual_seed(8), eta=0.5)
        assert torch.equal(a, b) and not torch.equal(a, c)
        assert a.abs().max() <= 1.0

    def test_guidance_combines_branches(self):
        f0 = make_f0().float()
        model = AffineEpsModel()
        g = torch.Generator().manual_seed(0)
        noise = torch.randn(f0.shape, generator=g)
        # eps_u + s (eps_c - eps_u) with eps_c = 0.9 x, eps_u = 0.7 x: s = 2 gives 1.1 x
        guided = ddim_sample(model, make_inputs(f0), 4, guidance_scale=2.0, noise=noise)

        class Scaled(AffineEpsModel):
            def forward(self, f_t, t, inputs, **kw):
                return DenoiserOutput(eps=1.1 * f_t + 0.3 * torch.sin(f_t + t[0] / 100.0), latents=f_t)
        expected = ddim_sample(Scaled(), make_inputs(f0), 4, noise=noise)
        torch.testing.assert_close(guided, expected, rtol=1e-6, atol=1e-6)


GOLDEN = json.loads((Path(__file__).parent / "golden" / "diffusers_ddim.json").read_text())


class TestAgainstDiffusers:
    """diffusers' DDIMScheduler outputs recorded by tests/golden/record_oracles.py (diffusers is not installed here)."""

    def test_alphas_cumprod(self):
        ref = torch.tensor(GOLDEN["alphas_cumprod"], dtype=torch.float64)
        assert ref.shape == (1000,)
        torch.testing.assert_close(cosine_alphas_cumprod(), ref, rtol=0, atol=1e-6)

    @pytest.mark.parametrize("num_steps", NUM_STEPS_CASES)
    def test_timesteps(self, num_steps):
        assert ddim_timesteps(num_steps).tolist() == GOLDEN["timesteps"][str(num_steps)]

    def test_add_noise(self):
        f0, eps, t = add_noise_inputs()
        assert t.tolist() == GOLDEN["add_noise"]["t"]
        ref = torch.tensor(GOLDEN["add_noise"]["f_t"])
        torch.testing.assert_close(q_sample(f0, t, eps), ref, rtol=0, atol=1e-6)

    @pytest.mark.parametrize("case", sorted(FULL_LOOP_CASES))
    def test_full_loop(self, case):
        clip_sample, use_clipped, eta = FULL_LOOP_CASES[case]
        model, f0 = AffineEpsModel(), make_f0().float()
        # same schedule values as diffusers (float32 cumprod) so only the loop is compared
        alphas_cumprod = torch.tensor(GOLDEN["alphas_cumprod"], dtype=torch.float32).double()
        ours = ddim_sample(model, make_inputs(f0), 50, torch.Generator().manual_seed(11), eta=eta,
                           clip_sample=clip_sample, use_clipped_model_output=use_clipped,
                           alphas_cumprod=alphas_cumprod)
        # unclipped samples reach |x| ~ 1e2 (the first step divides by sqrt(ab_999) = 5e-5, which
        # amplifies float32 rounding of a different operation order): there the bound is relative,
        # 4e-6 (measured 1.3e-6, ~20 float32 ulps), far below the eta=0 vs eta=1 gap checked below
        torch.testing.assert_close(ours, torch.tensor(GOLDEN["full_loop"][case]), rtol=4e-6, atol=1e-6)

    def test_golden_is_what_a_broken_sampler_would_miss(self):
        """The golden discriminates: eta=0 vs eta=1 loops differ by far more than the tolerance."""
        a, b = (torch.tensor(GOLDEN["full_loop"][k]) for k in ("clip", "clip_eta1"))
        assert (a - b).abs().max() > 1e-2
