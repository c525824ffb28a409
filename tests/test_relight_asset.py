"""gspi-relight: deferred split-sum shading of a PBR-GS asset (gspi/relight.py, gspi/cli/relight.py)."""
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf
from PIL import Image

from gspi.gaussians.ply import write_ply
from gspi.relight import (load_environment, orbit_cameras, rotate_environment, shade_asset,
                          to_display)
from tests.fixtures import surfel_sphere

CONF = Path(__file__).resolve().parents[1] / "conf" / "gspi_relight.yaml"


def constant_asset(albedo: float, roughness: float, metallic: float, num: int = 600):
    """A sphere of surfels whose every surfel has the same material (logits of exact values)."""
    g = surfel_sphere(num, radius=0.8, opacity=0.999)
    n = g.means.shape[0]

    def logit(p):
        p = min(max(p, 1e-7), 1 - 1e-7)
        return torch.full((n, 1), math.log(p / (1 - p)))

    return g.with_pbr(logit(albedo).expand(n, 3).clone(), logit(roughness), logit(metallic))


def cameras(size=32):
    return orbit_cameras([0.0, 120.0], [20.0, -30.0], radius=3.0, target=[0, 0, 0], width=size,
                         height=size, fov_deg=40.0)


class TestFurnace:
    L = 0.5

    def env(self):
        return torch.full((16, 32, 3), self.L)

    def test_white_mirror_metal_is_invisible(self):
        """Furnace: a white, smooth metal under a constant sky reflects exactly the sky, L."""
        w2c, K = cameras()
        shaded = shade_asset(constant_asset(1.0, 0.0, 1.0), self.env(), w2c, K, 32, 32)
        inside = shaded.alpha[..., 0] > 0.99
        assert inside.sum() > 200  # the sphere covers the middle of both views
        values = shaded.radiance[inside]
        assert torch.allclose(values, torch.full_like(values, self.L), atol=2e-3)

    def test_diffuse_part_is_albedo_times_sky(self):
        """Same roughness and normals, two albedos: the difference is exactly L * (a1 - a2)
        (irradiance of a constant sky is pi L; the specular part cancels)."""
        w2c, K = cameras()
        hi = shade_asset(constant_asset(0.8, 0.6, 0.0), self.env(), w2c, K, 32, 32)
        lo = shade_asset(constant_asset(0.2, 0.6, 0.0), self.env(), w2c, K, 32, 32)
        inside = hi.alpha[..., 0] > 0.99
        diff = (hi.radiance - lo.radiance)[inside]
        assert torch.allclose(diff, torch.full_like(diff, self.L * 0.6), atol=1e-4)
        # (the asset's albedo is linear: decoding it as sRGB would give L * 0.571 here)

    def test_background_and_exposure(self):
        w2c, K = cameras()
        shaded = shade_asset(constant_asset(1.0, 0.0, 1.0), self.env(), w2c, K, 32, 32)
        outside = shaded.alpha[..., 0] < 1e-4
        assert torch.all(shaded.radiance[outside] == 0)
        grey = to_display(shaded, tonemap_mode="clamp", background=(0.0, 1.0, 0.0))
        assert grey.dtype == np.uint8 and grey.shape == (2, 32, 32, 3)
        assert np.all(grey[outside.numpy()] == [0, 255, 0])
        inside = (shaded.alpha[..., 0] > 0.999).numpy()
        # L = 0.5 linear -> sRGB 0.735 (188); one stop up -> 1.0 (255)
        assert np.all(np.abs(grey[inside].astype(int) - 188) <= 1)
        bright = to_display(shaded, tonemap_mode="clamp", exposure_stops=1.0)
        assert np.all(bright[inside] >= 254)


def test_plain_2dgs_asset_is_refused():
    w2c, K = cameras()
    with pytest.raises(ValueError, match="no PBR attributes"):
        shade_asset(surfel_sphere(100), torch.ones(8, 16, 3), w2c, K, 32, 32)


def test_rotate_environment_turns_counter_clockwise():
    """A light at azimuth 0 (+x) comes from +90 degrees (+y) after turning by +90."""
    from eval.envmap import latlong_directions

    dirs = latlong_directions(8, 16)
    env = torch.zeros(8, 16, 3)
    row, col = 3, int(torch.argmax(dirs[3, :, 0]))            # the texel nearest +x
    env[row, col] = 1.0
    turned = rotate_environment(env, 90.0)
    brightest = dirs.reshape(-1, 3)[int(turned[..., 0].reshape(-1).argmax())]
    azimuth = math.degrees(math.atan2(float(brightest[1]), float(brightest[0])))
    assert abs(azimuth - 90.0) < 360 / 16 and torch.equal(rotate_environment(env, 360.0), env)


def test_load_environment_by_name_and_error():
    env = load_environment("meadow", height=8)
    assert env.shape == (8, 16, 3) and torch.isfinite(env).all() and env.min() >= 0
    with pytest.raises(ValueError, match="known names: .*meadow"):
        load_environment("no_such_sky")


def test_cli_writes_frames_animation_and_stills(tmp_path):
    from gspi.cli.relight import run

    asset = tmp_path / "pbr_gs.ply"
    write_ply(asset, constant_asset(0.7, 0.4, 0.0, num=300))
    cfg = OmegaConf.load(CONF)
    cfg.asset, cfg.env, cfg.out = str(asset), "neon", str(tmp_path / "out")
    cfg.size, cfg.frames, cfg.env_height, cfg.views = 24, 4, 8, [[0, 10], [90, 60]]
    record = run(cfg)
    assert len(record["frames"]) == 4 and len(record["views"]) == 2
    webp = Image.open(record["animation"])
    assert webp.format == "WEBP" and webp.n_frames == 4 and webp.size == (24, 24)
    frames = [np.asarray(Image.open(p)) for p in record["frames"]]
    assert all(f.shape == (24, 24, 3) for f in frames)
    centre = frames[0][12, 12]
    assert not np.all(centre == 255)  # the asset, not the white background, is in the middle
    assert (tmp_path / "out" / "relight.json").is_file()


def test_cli_spin_env_changes_the_lighting(tmp_path):
    from gspi.cli.relight import run

    asset = tmp_path / "pbr_gs.ply"
    write_ply(asset, constant_asset(0.7, 0.1, 1.0, num=300))
    cfg = OmegaConf.load(CONF)
    cfg.asset, cfg.env, cfg.out = str(asset), "neon", str(tmp_path / "out")
    cfg.size, cfg.frames, cfg.env_height, cfg.spin, cfg.animation = 24, 2, 8, "env", "none"
    record = run(cfg)
    a, b = (np.asarray(Image.open(p)).astype(int) for p in record["frames"])
    assert record["animation"] is None
    assert np.abs(a - b).max() > 10  # same camera, environment turned by 180 degrees


def test_cli_missing_asset_is_a_clear_error(tmp_path):
    from gspi.cli.relight import run

    cfg = OmegaConf.load(CONF)
    cfg.asset, cfg.env, cfg.out = str(tmp_path / "nope.ply"), "meadow", str(tmp_path)
    with pytest.raises(FileNotFoundError, match="nope.ply: asset file not found"):
        run(cfg)
