"""Procedural HDR environment maps (lat-long, Z-up, linear radiance) of the benchmark.

Two disjoint, fixed sets of named environments: `CAPTURE_ENVS` (8; a scene's input images are
rendered under one of them) and `HELDOUT_ENVS` (6; relighting ground truth only, never seen in
the inputs). An environment is a sum of analytic radiance terms evaluated per texel direction
(`eval.envmap.latlong_directions`, the project's lat-long convention), 4x4 supersampled per texel
so small lights keep their energy at any resolution:

* sky: zenith/horizon gradient over a darker ground, with a sun disc (angular radius 3 deg)
  whose radiance is `sun_ratio` (10^3 - 10^4) times the mean sky radiance, plus a glow;
* studio/interior: a backdrop gradient and coloured area lights (soft-edged angular
  rectangles and discs): softboxes, rim lights, strip lights, windows, neon tubes.

Exposure: every map is scaled so that the largest diffuse irradiance over all normals,
max_n E(n), equals pi * `white_radiance` (default 1): a white Lambertian surface facing the
brightest direction renders at radiance ~1, so objects land in a sane range while glossy
highlights stay HDR. The parameters of each named environment are fixed (not seeded), so an
environment name means the same lighting in every dataset; only the resolution varies.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from eval.envmap import latlong_directions

SUN_RADIUS_DEG = 3.0


def _dir(azimuth_deg: float, elevation_deg: float) -> Tensor:
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return torch.tensor([math.cos(a) * math.cos(e), math.sin(a) * math.cos(e), math.sin(e)])


def _sky(d: Tensor, zenith, horizon, ground) -> Tensor:
    z = d[:, 2:3]
    up = z.clamp_min(0.0) ** 0.5
    sky = torch.tensor(horizon) * (1 - up) + torch.tensor(zenith) * up
    blend = torch.sigmoid(z * 40.0)  # soft horizon
    return sky * blend + torch.tensor(ground) * (1 - blend)


def _disc(d: Tensor, center: Tensor, radius_deg: float, soft_deg: float = 0.5) -> Tensor:
    ang = torch.rad2deg(torch.arccos((d @ center).clamp(-1.0, 1.0)))
    return ((radius_deg + soft_deg - ang) / (2 * soft_deg)).clamp(0.0, 1.0)[:, None]


def _rect(d: Tensor, center: Tensor, half_w_deg: float, half_h_deg: float,
          soft_deg: float = 1.0) -> Tensor:
    """Angular rectangle facing the origin at `center`, its long side horizontal."""
    up = torch.tensor([0.0, 0.0, 1.0])
    u = torch.linalg.cross(up.expand_as(center), center)
    u = u / u.norm() if u.norm() > 1e-6 else torch.tensor([1.0, 0.0, 0.0])
    v = torch.linalg.cross(center, u)
    z = d @ center
    x = torch.rad2deg(torch.atan2(d @ u, z)).abs()
    y = torch.rad2deg(torch.atan2(d @ v, z)).abs()
    wx = ((half_w_deg + soft_deg - x) / (2 * soft_deg)).clamp(0.0, 1.0)
    wy = ((half_h_deg + soft_deg - y) / (2 * soft_deg)).clamp(0.0, 1.0)
    return (wx * wy * (z > 0))[:, None]


def _sky_env(d: Tensor, *, zenith, horizon, ground, sun_az: float, sun_el: float,
             sun_ratio: float, sun_colour=(1.0, 0.95, 0.85), glow: float = 0.0) -> Tensor:
    sky = _sky(d, zenith, horizon, ground)
    if sun_ratio <= 0:
        return sky
    c = _dir(sun_az, sun_el)
    mean_sky = float(torch.tensor(zenith).mean() + torch.tensor(horizon).mean()) / 2
    sun = _disc(d, c, SUN_RADIUS_DEG) * torch.tensor(sun_colour) * sun_ratio * mean_sky
    halo = glow * mean_sky * torch.exp(-torch.arccos((d @ c).clamp(-1, 1)) / 0.15)[:, None]
    return sky + sun + halo * torch.tensor(sun_colour)


def _studio_env(d: Tensor, *, backdrop, floor, lights) -> Tensor:
    """lights: tuples ("rect", az, el, half_w, half_h, rgb) or ("disc", az, el, radius, rgb)."""
    out = _sky(d, backdrop, [0.5 * (a + b) for a, b in zip(backdrop, floor)], floor)
    for light in lights:
        if light[0] == "rect":
            _, az, el, hw, hh, rgb = light
            out = out + _rect(d, _dir(az, el), hw, hh) * torch.tensor(rgb)
        else:
            _, az, el, rad, rgb = light
            out = out + _disc(d, _dir(az, el), rad, soft_deg=1.0) * torch.tensor(rgb)
    return out


BLUE_SKY = dict(zenith=(0.25, 0.45, 0.9), horizon=(0.75, 0.85, 1.0), ground=(0.25, 0.22, 0.2))
CAPTURE_ENVS = {
    "sky_noon": ("sky", dict(**BLUE_SKY, sun_az=30, sun_el=65, sun_ratio=3000, glow=2.0)),
    "sky_morning": ("sky", dict(zenith=(0.3, 0.45, 0.8), horizon=(0.95, 0.85, 0.75),
                                ground=(0.22, 0.2, 0.18), sun_az=120, sun_el=25, sun_ratio=2000,
                                sun_colour=(1.0, 0.85, 0.65), glow=4.0)),
    "sunset": ("sky", dict(zenith=(0.15, 0.2, 0.45), horizon=(1.0, 0.55, 0.25),
                           ground=(0.12, 0.08, 0.07), sun_az=200, sun_el=6, sun_ratio=1500,
                           sun_colour=(1.0, 0.6, 0.3), glow=8.0)),
    "overcast": ("sky", dict(zenith=(0.9, 0.92, 0.95), horizon=(0.6, 0.62, 0.65),
                             ground=(0.2, 0.2, 0.19), sun_az=0, sun_el=0, sun_ratio=0)),
    "studio_softbox": ("studio", dict(backdrop=(0.15, 0.15, 0.15), floor=(0.05, 0.05, 0.05), lights=[
        ("rect", 45, 35, 20, 14, (40.0, 40.0, 38.0)), ("rect", 200, 20, 25, 18, (12.0, 12.0, 13.0))])),
    "studio_rgb": ("studio", dict(backdrop=(0.05, 0.05, 0.06), floor=(0.02, 0.02, 0.02), lights=[
        ("disc", 0, 30, 10, (90.0, 15.0, 10.0)), ("disc", 120, 45, 10, (10.0, 80.0, 30.0)),
        ("disc", 240, 20, 10, (15.0, 25.0, 100.0))])),
    "warehouse": ("studio", dict(backdrop=(0.3, 0.26, 0.2), floor=(0.12, 0.1, 0.08), lights=[
        ("rect", az, 60, 4, 25, (60.0, 55.0, 45.0)) for az in (0, 60, 120, 180, 240, 300)])),
    "window_room": ("studio", dict(backdrop=(0.2, 0.17, 0.14), floor=(0.1, 0.08, 0.06), lights=[
        ("rect", 90, 15, 30, 20, (30.0, 35.0, 45.0)), ("disc", 300, 40, 6, (120.0, 80.0, 40.0))])),
}
HELDOUT_ENVS = {
    "sky_afternoon": ("sky", dict(zenith=(0.2, 0.4, 0.85), horizon=(0.8, 0.85, 0.95),
                                  ground=(0.3, 0.25, 0.2), sun_az=260, sun_el=45, sun_ratio=5000,
                                  glow=2.0)),
    "dusk": ("sky", dict(zenith=(0.1, 0.08, 0.3), horizon=(0.9, 0.4, 0.5), ground=(0.08, 0.06, 0.08),
                         sun_az=330, sun_el=8, sun_ratio=1200, sun_colour=(1.0, 0.5, 0.45),
                         glow=10.0)),
    "studio_rim": ("studio", dict(backdrop=(0.03, 0.03, 0.04), floor=(0.01, 0.01, 0.01), lights=[
        ("rect", 180, 25, 8, 30, (20.0, 90.0, 100.0)),
        ("rect", 330, 40, 15, 12, (100.0, 60.0, 25.0))])),
    "neon": ("studio", dict(backdrop=(0.02, 0.02, 0.03), floor=(0.03, 0.02, 0.03), lights=[
        ("rect", 60, 10, 40, 2, (120.0, 10.0, 90.0)),
        ("rect", 240, 50, 3, 30, (10.0, 110.0, 120.0))])),
    "meadow": ("sky", dict(zenith=(0.7, 0.75, 0.85), horizon=(0.85, 0.88, 0.9),
                           ground=(0.2, 0.35, 0.12), sun_az=150, sun_el=35, sun_ratio=1000,
                           glow=1.0)),
    "skylight": ("studio", dict(backdrop=(0.08, 0.08, 0.09), floor=(0.05, 0.04, 0.04), lights=[
        ("rect", 0, 89, 25, 25, (30.0, 30.0, 32.0))])),
}


def env_names(kind: str) -> list[str]:
    """Names of the `capture` or `heldout` environments, in their fixed order."""
    if kind == "capture":
        return list(CAPTURE_ENVS)
    if kind == "heldout":
        return list(HELDOUT_ENVS)
    raise ValueError(f"unknown environment set {kind!r}; allowed: capture, heldout")


def _radiance(name: str, d: Tensor) -> Tensor:
    table = CAPTURE_ENVS if name in CAPTURE_ENVS else HELDOUT_ENVS
    if name not in table:
        raise ValueError(f"unknown environment {name!r}; allowed: "
                         f"{', '.join([*CAPTURE_ENVS, *HELDOUT_ENVS])}")
    kind, params = table[name]
    return _sky_env(d, **params) if kind == "sky" else _studio_env(d, **params)


def normalise_exposure(env: Tensor, *, white_radiance: float = 1.0) -> Tensor:
    """Scale `env` [H, W, 3] so that max over normals of the diffuse irradiance = pi * white."""
    from eval.relight import irradiance_map

    irr = irradiance_map(env, height=min(32, env.shape[0]))
    peak = float(irr.mean(dim=-1).max())
    return env * (math.pi * white_radiance / max(peak, 1e-12))


def make_environment(name: str, height: int, width: int | None = None, *,
                     supersample: int = 4, white_radiance: float = 1.0) -> Tensor:
    """Render the named environment.

    Args:
        name: a key of CAPTURE_ENVS or HELDOUT_ENVS.
        height, width: lat-long size (width defaults to 2 * height).
        supersample: s x s directions per texel, averaged (anti-aliasing small lights).
    Returns:
        [H, W, 3] float32 linear HDR radiance, exposure-normalised.
    """
    width = 2 * height if width is None else width
    fine = latlong_directions(height * supersample, width * supersample).reshape(-1, 3)
    rad = _radiance(name, fine).reshape(height, supersample, width, supersample, 3)
    # Sub-texel rows have different solid angles; weight by cos(elevation) of each sub-row.
    w = fine[:, 2].reshape(height, supersample, width, supersample)[..., :1].clone()
    w = torch.sqrt((1.0 - w * w).clamp_min(0.0))[..., None]  # [H, s, W, 1, 1]
    env = (rad * w).sum(dim=(1, 3)) / (supersample * w.sum(dim=(1, 3)))
    return normalise_exposure(env.float().contiguous(), white_radiance=white_radiance)
