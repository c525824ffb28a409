"""Tests for gspi.gaussians.cameras (OpenCV axes, pixel centres at +0.5)."""

from __future__ import annotations

import math

import torch

from gspi.gaussians.cameras import camera_centers, intrinsics_from_fov, look_at, pixel_rays, unproject

DT = torch.float64


def transform(w2c: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    return p @ w2c[:3, :3].T + w2c[:3, 3]


class TestLookAt:
    def test_axes(self):
        center = torch.tensor([1.0, 2.0, 3.0], dtype=DT)
        target = torch.tensor([0.0, 0.5, -1.0], dtype=DT)
        up = torch.tensor([0.0, 0.0, 1.0], dtype=DT)
        w2c = look_at(center, target, up)
        rot = w2c[:3, :3]
        torch.testing.assert_close(rot @ rot.T, torch.eye(3, dtype=DT))
        assert torch.det(rot) > 0
        torch.testing.assert_close(transform(w2c, center), torch.zeros(3, dtype=DT))
        t_cam = transform(w2c, target)
        torch.testing.assert_close(t_cam[:2], torch.zeros(2, dtype=DT))
        assert t_cam[2] > 0  # z forward
        assert (rot @ up)[1] < 0  # world up is image up = -y (y down)
        assert abs(float((rot @ up)[0])) < 1e-12  # no roll
        torch.testing.assert_close(camera_centers(w2c), center)

    def test_pole_is_valid(self):
        w2c = look_at(torch.tensor([0.0, 0.0, 4.0]), torch.zeros(3), torch.tensor([0.0, 0.0, 1.0]))
        rot = w2c[:3, :3]
        assert torch.isfinite(w2c).all()
        torch.testing.assert_close(rot @ rot.T, torch.eye(3), atol=1e-6, rtol=0)
        torch.testing.assert_close(transform(w2c, torch.zeros(3)), torch.tensor([0.0, 0.0, 4.0]))

    def test_batched(self):
        centers = torch.randn(6, 3, dtype=DT) * 3
        w2c = look_at(centers, torch.zeros(3, dtype=DT), torch.tensor([0.0, 1.0, 0.0], dtype=DT))
        assert w2c.shape == (6, 4, 4)
        torch.testing.assert_close(camera_centers(w2c), centers)


def test_intrinsics_from_fov():
    K = intrinsics_from_fov(math.radians(60), 80, 40)
    f = 80 / (2 * math.tan(math.radians(30)))
    torch.testing.assert_close(K, torch.tensor([[f, 0, 40.0], [0, f, 20.0], [0, 0, 1]]))


def test_pixel_rays_and_unproject_round_trip():
    up = torch.tensor([0.0, 0.0, 1.0], dtype=DT)
    w2c = look_at(torch.tensor([2.0, -1.0, 3.0], dtype=DT), torch.zeros(3, dtype=DT), up)
    K = intrinsics_from_fov(math.radians(50), 9, 7, dtype=DT)
    rays = pixel_rays(K, w2c, 7, 9)
    assert rays.shape == (7, 9, 3)
    torch.testing.assert_close(rays.norm(dim=-1), torch.ones(7, 9, dtype=DT))
    # the centre pixel of an odd image looks along the optical axis
    torch.testing.assert_close(rays[3, 4], w2c[2, :3])
    depth = torch.rand(7, 9, dtype=DT) + 1.0
    pts = unproject(depth[..., None], K, w2c)
    cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
    torch.testing.assert_close(cam[..., 2], depth)  # z-depth, not ray length
    pix = cam @ K.T
    pix = pix[..., :2] / pix[..., 2:]
    ys, xs = torch.meshgrid(torch.arange(7, dtype=DT) + 0.5, torch.arange(9, dtype=DT) + 0.5, indexing="ij")
    torch.testing.assert_close(pix, torch.stack([xs, ys], -1))
    # points lie on the pixel rays
    dirs = torch.nn.functional.normalize(pts - camera_centers(w2c), dim=-1)
    torch.testing.assert_close(dirs, rays)
    torch.testing.assert_close(unproject(depth, K, w2c), pts)
