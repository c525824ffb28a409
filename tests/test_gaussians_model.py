"""Tests for gspi.gaussians.model (Gaussians2D) and gspi.gaussians.sh."""

from __future__ import annotations

import math

import pytest
import torch

from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.projection import quat_to_rotmat
from tests.fixtures import random_gaussians
from gspi.gaussians.sh import SH_C0, eval_sh, num_sh_bases, rgb_to_sh, sh_colors, sh_degree_from_bases, sh_to_rgb


def make(n: int = 4, degree: int = 2, pbr: bool = True) -> Gaussians2D:
    return random_gaussians(n, degree, pbr, seed=1)


class TestGaussians2D:
    def test_sizes(self):
        g = make(5, 2)
        assert g.num_gaussians == 5 and g.sh_degree == 2 and g.has_pbr
        assert g.sh.shape == (5, 9, 3)

    def test_activations(self):
        g = make()
        torch.testing.assert_close(g.scales, torch.exp(g.log_scales))
        torch.testing.assert_close(g.opacities, torch.sigmoid(g.opacity_logits))
        torch.testing.assert_close(g.rotations.norm(dim=-1), torch.ones(4))
        torch.testing.assert_close(g.albedo, torch.sigmoid(g.albedo_logits))
        f = g.pbr_features()
        assert f.shape == (4, 5) and (f > 0).all() and (f < 1).all()
        torch.testing.assert_close(f[:, 3:], torch.cat([g.roughness, g.metallic], -1))

    def test_base_color(self):
        g = make()
        torch.testing.assert_close(g.base_color(), 0.5 + SH_C0 * g.sh_dc[:, 0])

    def test_normals_are_rotation_column_2(self):
        g = make()
        torch.testing.assert_close(g.normals, quat_to_rotmat(g.quats)[..., 2])

    def test_pbr_absent(self):
        g = make(pbr=False)
        assert not g.has_pbr
        with pytest.raises(ValueError, match="no PBR"):
            g.albedo

    @pytest.mark.parametrize(
        "field,value",
        [("log_scales", torch.zeros(4, 3)), ("opacity_logits", torch.zeros(4, 1)), ("sh_rest", torch.zeros(4, 5, 3))],
    )
    def test_shape_validation(self, field, value):
        kwargs = {f: getattr(make(), f) for f in ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")}
        kwargs[field] = value
        with pytest.raises(ValueError):
            Gaussians2D(**kwargs)

    def test_partial_pbr_rejected(self):
        g = make(pbr=False)
        with pytest.raises(ValueError, match="all set or all None"):
            Gaussians2D(
                g.means, g.quats, g.log_scales, g.opacity_logits, g.sh_dc, g.sh_rest, albedo_logits=torch.zeros(4, 3)
            )

    def test_to_subset_clone_detach(self):
        g = make()
        h = g.to(torch.float64)
        assert h.means.dtype == torch.float64 and h.albedo_logits.dtype == torch.float64
        s = g.subset(torch.tensor([True, False, True, False]))
        assert s.num_gaussians == 2 and s.has_pbr
        torch.testing.assert_close(s.sh_rest, g.sh_rest[[0, 2]])
        c = g.clone()
        c.means += 1
        assert not torch.equal(c.means, g.means)
        g.means.requires_grad_()
        assert not g.detach().means.requires_grad

    def test_empty(self):
        g = Gaussians2D.empty(3, sh_degree=1, pbr=True)
        assert g.sh_degree == 1 and g.num_gaussians == 3
        torch.testing.assert_close(g.opacities, torch.full((3,), 0.5))
        torch.testing.assert_close(g.base_color(), torch.full((3, 3), 0.5))

    def test_colors_view_dependent(self):
        g = make(degree=3)
        cam = torch.tensor([0.0, 0.0, -5.0])
        expected = torch.clamp_min(eval_sh(3, g.sh, g.means - cam) + 0.5, 0.0)
        torch.testing.assert_close(g.colors(cam), expected)
        torch.testing.assert_close(g.colors(cam, degree=0), torch.clamp_min(g.base_color(), 0.0))


def fibonacci_sphere(n: int) -> torch.Tensor:
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = torch.sqrt(1 - z * z)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


class TestSH:
    def test_bases_count(self):
        assert [num_sh_bases(d) for d in range(4)] == [1, 4, 9, 16]
        assert sh_degree_from_bases(16) == 3
        with pytest.raises(ValueError):
            sh_degree_from_bases(5)

    def test_rgb_sh_inverse(self):
        rgb = torch.rand(6, 3)
        torch.testing.assert_close(sh_to_rgb(rgb_to_sh(rgb)), rgb)

    def test_basis_is_orthonormal(self):
        # the 16 real SH basis functions are orthonormal on the sphere (checks every constant)
        dirs = fibonacci_sphere(20000)
        basis = []
        for k in range(16):
            coef = torch.zeros(16, 3, dtype=torch.float64)
            coef[k, 0] = 1.0
            basis.append(eval_sh(3, coef.expand(len(dirs), 16, 3), dirs)[:, 0])
        y = torch.stack(basis, -1)
        gram = y.T @ y * (4 * math.pi / len(dirs))
        torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=2e-3, rtol=0)

    def test_known_values_inria_signs(self):
        # Inria basis: index 1 = -C1 y, 2 = C1 z, 3 = -C1 x
        for k, d, v in [(1, [0, 1, 0], -0.4886025119029199), (2, [0, 0, 1], 0.4886025119029199),
                        (3, [1, 0, 0], -0.4886025119029199), (6, [0, 0, 1], 2 * 0.31539156525252005)]:
            coef = torch.zeros(1, 16, 3, dtype=torch.float64)
            coef[0, k] = 1.0
            out = eval_sh(3, coef, torch.tensor([d], dtype=torch.float64) * 3.0)  # unnormalised direction
            torch.testing.assert_close(out[0], torch.full((3,), v, dtype=torch.float64))

    def test_lower_degree_ignores_higher_bands(self):
        sh = torch.randn(5, 16, 3)
        dirs = torch.randn(5, 3)
        torch.testing.assert_close(eval_sh(1, sh, dirs), eval_sh(1, sh[:, :4], dirs))
        with pytest.raises(ValueError):
            eval_sh(2, sh[:, :4], dirs)

    def test_sh_colors_clamped(self):
        sh = torch.zeros(2, 1, 3)
        sh[0, 0] = -10.0
        out = sh_colors(0, sh, torch.zeros(2, 3), torch.tensor([0.0, 0.0, -1.0]))
        torch.testing.assert_close(out, torch.tensor([[0.0] * 3, [0.5] * 3]))
