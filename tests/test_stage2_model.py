"""Tests of the Stage II RCW denoiser, its inputs, normalisation and training objective (tiny CPU sizes)."""
import dataclasses

import pytest
import torch

from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.loss import denoising_loss
from gspi.stage2.model import RCWConfig, RCWDenoiser, count_parameters
from gspi.stage2.normalize import (fit_unit_sphere, from_unit_sphere, pbr_from_model, pbr_to_model,
                                   to_unit_sphere, view_onehot)
from gspi.stage2.sampler import ddim_sample

TINY = RCWConfig(num_latents=16, latent_dim=32, point_dim=16, num_blocks=2, num_compute_layers=1, num_heads=2,
                 fourier_bands=2, global_token_dim=8)


def make_model(config=TINY, seed=0):
    torch.manual_seed(seed)
    return RCWDenoiser(config).eval()


def make_inputs(b=2, n=64, v=4, config=TINY, seed=0):
    g = torch.Generator().manual_seed(seed)
    xyz = torch.rand(b, n, 3, generator=g) * 2 - 1
    local = torch.rand(b, n, config.local_cond_dim, generator=g)
    tokens = None
    if v and config.global_token_dim:
        tokens = torch.randn(b, v, 25, config.global_token_dim, generator=g)
    view_ids = None if tokens is None else torch.stack([torch.randperm(32, generator=g)[:v] for _ in range(b)])
    f_t = torch.randn(b, n, 5, generator=g)
    return f_t, Stage2Inputs(xyz=xyz, local_cond=local, global_tokens=tokens, view_ids=view_ids)


class TestRCWDenoiser:
    @pytest.mark.parametrize("n", [7, 64, 300])
    @pytest.mark.parametrize("v", [0, 16, 32])
    def test_shapes(self, n, v):
        model = make_model()
        f_t, inputs = make_inputs(n=n, v=v)
        out = model(f_t, torch.tensor([0, 999]), inputs)
        assert out.eps.shape == (2, n, 5)
        assert out.latents.shape == (2, TINY.num_latent_tokens(v), 32)
        assert torch.isfinite(out.eps).all()

    def test_permutation_equivariance(self):
        model = make_model()
        f_t, inputs = make_inputs(n=50)
        perm = torch.randperm(50, generator=torch.Generator().manual_seed(3))
        permuted = dataclasses.replace(inputs, xyz=inputs.xyz[:, perm], local_cond=inputs.local_cond[:, perm])
        with torch.no_grad():
            out, out_p = model(f_t, 500, inputs), model(f_t[:, perm], 500, permuted)
        torch.testing.assert_close(out_p.eps, out.eps[:, perm], rtol=0, atol=1e-5)
        torch.testing.assert_close(out_p.latents, out.latents, rtol=0, atol=1e-5)

    def test_deterministic(self):
        f_t, inputs = make_inputs()
        a = make_model(seed=1)(f_t, 10, inputs).eps
        b = make_model(seed=1)(f_t, 10, inputs).eps
        assert torch.equal(a, b)

    def test_chunked_write_equals_unchunked(self):
        model = make_model()
        f_t, inputs = make_inputs(n=300)
        with torch.no_grad():
            full = model(f_t, 300, inputs).eps
            chunked = model(f_t, 300, inputs, write_chunk=64).eps
        torch.testing.assert_close(chunked, full, rtol=0, atol=1e-6)

    def test_self_conditioning_is_noop_at_init(self):
        model = make_model()
        f_t, inputs = make_inputs()
        with torch.no_grad():
            first = model(f_t, 100, inputs)
            second = model(f_t, 100, inputs, prev_latents=torch.randn_like(first.latents))
        assert torch.equal(first.eps, second.eps)

    def test_view_ids_and_null_condition_matter(self):
        model = make_model()
        with torch.no_grad():
            f_t, inputs = make_inputs(v=4)
            base = model(f_t, 100, inputs).eps
            shifted = dataclasses.replace(inputs, view_ids=(inputs.view_ids + 1) % 32)
            assert not torch.allclose(model(f_t, 100, shifted).eps, base)
            dropped = model(f_t, 100, inputs, cond_keep=torch.tensor([True, False])).eps
        torch.testing.assert_close(dropped[0], base[0], rtol=0, atol=1e-6)
        assert not torch.allclose(dropped[1], base[1])

    @pytest.mark.parametrize("name,changes,width", [
        ("A1_no_global_prior", dict(global_token_dim=0), 35),
        ("A2_no_view_onehot", dict(use_view_onehot=False, local_cond_dim=3), 3),
        ("A5_direct_multiview", dict(use_view_onehot=False, local_cond_dim=128), 128),
    ])
    def test_ablation_configs(self, name, changes, width):
        config = dataclasses.replace(TINY, **changes)
        model = make_model(config)
        f_t, inputs = make_inputs(n=20, v=3, config=config)
        assert inputs.local_cond.shape[-1] == width
        assert model(f_t, 5, inputs).eps.shape == (2, 20, 5)
        with pytest.raises(ValueError):
            model(f_t, 5, dataclasses.replace(inputs, local_cond=torch.zeros(2, 20, width + 1)))
        if config.global_token_dim == 0:
            assert inputs.global_tokens is None
            with pytest.raises(ValueError):
                model(f_t, 5, dataclasses.replace(inputs, global_tokens=torch.zeros(2, 3, 25, 8)))

    def test_config_validation(self):
        with pytest.raises(ValueError):
            RCWConfig(latent_dim=30, num_heads=4)
        with pytest.raises(ValueError):
            RCWConfig(local_cond_dim=3)  # the one-hot needs 32 channels
        with pytest.raises(TypeError):
            RCWConfig(256)  # keyword-only

    def test_default_config_size(self):
        with torch.device("meta"):  # no memory, no init work
            model = RCWDenoiser(RCWConfig())
        assert count_parameters(model) == 241_110_021  # PointInfinity sizes + GS-PI inputs


class TestTraining:
    def test_overfits_fixed_batch(self):
        config = dataclasses.replace(TINY, cond_drop_prob=0.0)
        model = make_model(config).train()
        _, inputs = make_inputs(b=4, n=32, v=2, config=config)
        f0 = pbr_to_model(torch.rand(4, 32, 5, generator=torch.Generator().manual_seed(5)))
        optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)

        def fixed_loss():
            return denoising_loss(model, f0, inputs, generator=torch.Generator().manual_seed(0))
        with torch.no_grad():
            initial = fixed_loss().item()
        for _ in range(30):
            optimizer.zero_grad()
            loss = fixed_loss()
            loss.backward()
            optimizer.step()
        with torch.no_grad():
            assert fixed_loss().item() < 0.5 * initial

    def test_sampling_is_deterministic(self):
        model = make_model()
        _, inputs = make_inputs(n=40, v=2)
        a = ddim_sample(model, inputs, 3, torch.Generator().manual_seed(4), guidance_scale=1.5, write_chunk=16)
        b = ddim_sample(model, inputs, 3, torch.Generator().manual_seed(4), guidance_scale=1.5)
        assert a.shape == (2, 40, 5) and a.abs().max() <= 1
        torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


class TestStage2Inputs:
    def test_select_views(self):
        _, inputs = make_inputs(v=6)
        keep = torch.tensor([[5, 0], [2, 3]])
        sub = inputs.select_views(keep)
        assert sub.num_views == 2 and sub.global_tokens.shape == (2, 2, 25, 8)
        assert torch.equal(sub.view_ids, torch.gather(inputs.view_ids, 1, keep))
        torch.testing.assert_close(sub.global_tokens[1, 0], inputs.global_tokens[1, 2])

    def test_rejects_bad_shapes(self):
        with pytest.raises(ValueError):
            Stage2Inputs(xyz=torch.zeros(1, 4, 3), local_cond=torch.zeros(1, 5, 35))
        with pytest.raises(ValueError):
            Stage2Inputs(xyz=torch.zeros(1, 4, 3), local_cond=torch.zeros(1, 4, 35),
                         global_tokens=torch.zeros(1, 2, 25, 8), view_ids=torch.zeros(1, 3))


class TestNormalize:
    def test_unit_sphere_round_trip(self):
        xyz = torch.randn(2, 100, 3, generator=torch.Generator().manual_seed(0)) * 5 + 3
        frame = fit_unit_sphere(xyz)
        unit = to_unit_sphere(xyz, frame)
        assert torch.allclose(unit.norm(dim=-1).amax(-1), torch.ones(2))
        bbox_center = 0.5 * (unit.amin(-2) + unit.amax(-2))
        torch.testing.assert_close(bbox_center, torch.zeros(2, 3), rtol=0, atol=1e-6)
        torch.testing.assert_close(from_unit_sphere(unit, frame), xyz, rtol=1e-6, atol=1e-5)

    def test_pbr_round_trip_and_clamp(self):
        v = torch.tensor([[0.0, 0.25, 0.5, 0.75, 1.0]])
        torch.testing.assert_close(pbr_to_model(v), torch.tensor([[-1.0, -0.5, 0.0, 0.5, 1.0]]))
        torch.testing.assert_close(pbr_from_model(pbr_to_model(v)), v)
        assert pbr_from_model(torch.tensor([[-3.0, 3.0, 0, 0, 0]]))[0, :2].tolist() == [0.0, 1.0]

    def test_view_onehot(self):
        assert view_onehot(torch.tensor([0, 31])).sum(-1).tolist() == [1.0, 1.0]


def test_point_global_skip_feeds_the_pooled_prior_to_every_point():
    """stage2.model.point_global_skip: the point tokens see LN(mean of the global tokens); off by
    default (the paper's model, unchanged), and dropped with the condition (CFG)."""
    skip = dataclasses.replace(TINY, point_global_skip=True)
    f_t, inputs = make_inputs(config=skip)
    model = make_model(skip)
    assert count_parameters(model) == count_parameters(make_model()) + 2 * 8 + 8 * 16 + 16
    plain = make_model(TINY)
    points_plain = plain.embed_points(f_t, inputs, None)
    points_skip = model.embed_points(f_t, inputs, None)
    other = dataclasses.replace(inputs, global_tokens=inputs.global_tokens + 1.0)
    assert torch.equal(plain.embed_points(f_t, other, None), points_plain)   # no path without the skip
    assert not torch.allclose(model.embed_points(f_t, other, None), points_skip)
    drop = torch.zeros(2, 1, 1)
    torch.testing.assert_close(model.embed_points(f_t, other, drop), model.embed_points(f_t, inputs, drop))
    loss = denoising_loss(model.train(), pbr_to_model(torch.rand(2, 64, 5)), inputs,
                          generator=torch.Generator().manual_seed(0))
    loss.backward()
    assert torch.isfinite(loss) and model.point_global_proj.weight.grad.abs().sum() > 0
