"""Time of the light estimate and the per-point read-out at a `small` scene's size, one thread:
the points ``method=light_fit`` reads on the demo's assets (``max_points``, capped at
``points_per_gaussian`` x the median demo asset's Gaussians) seen by 14 views each (the lattice's median), the 8 procedural capture environments
as candidates at 64 rows (``stage2.data.light_env_height`` / ``method.env_height``), the views
shaded by the split-sum shader under one of them turned and scaled; the estimate on
``method=light_fit``'s ``identify_points`` (all, and its coarse search on ``identify_coarse_points``
of them) and the read-out without and with its normal search (one normal, and its profile over
``normal_profile`` normals; conf/method/light_fit.yaml).
Target (issue 66): estimate + read-out <= 20 s a scene. Prints the
medians, the machine and whether the light was found.

    python -m benchmarks.bench_light [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from benchmarks.common import REPO, machine, median_seconds
from eval.relight import prefilter_environment, split_sum
from gspi.data.environments import CAPTURE_ENVS, make_environment
from gspi.gaussians.ply import read_ply
from gspi.light.estimate import estimate_light
from gspi.light.observations import PointViews
from gspi.light.readout import fit_grid, fit_grid_normal_search, pool_neighbours, read_posterior
from gspi.light.shading import turn_directions
from gspi.stage2.light_fit import LightFitConfig

VIEWS, ENV_HEIGHT = 14, 64
TRUTH, TURN, GAIN = "window_room", 75.0, 1.3
LIGHT_FIT = LightFitConfig.shipped()  # method=light_fit's settings
DEMO_ASSETS = REPO / "checkpoints" / "demo_assets"


def demo_points() -> tuple[int, int]:
    """(the points light_fit reads on the demo's median asset (its ``max_points`` capped per
    Gaussian), that asset's Gaussians)."""
    gaussians = int(statistics.median(read_ply(p).num_gaussians for p in sorted(DEMO_ASSETS.glob("*/point_cloud.ply"))))
    return LIGHT_FIT.for_asset(gaussians).max_points, gaussians


def scene(pre, num_points: int) -> PointViews:
    g = torch.Generator().manual_seed(0)
    normal = torch.nn.functional.normalize(torch.randn(num_points, 3, generator=g), dim=-1)
    point = torch.arange(num_points).repeat_interleave(VIEWS)
    n = normal[point]
    d = torch.nn.functional.normalize(n + 0.9 * torch.nn.functional.normalize(torch.randn(len(point), 3, generator=g), dim=-1), dim=-1)
    d = torch.where((d * n).sum(-1, keepdim=True) > 0.15, d, n)
    rough = torch.rand(num_points, generator=g)[point, None]
    metal = (torch.rand(num_points, generator=g) > 0.5).float()[point, None]
    albedo = torch.rand(num_points, 3, generator=g)[point]
    colour = GAIN * split_sum(albedo, rough, metal, turn_directions(n, TURN), turn_directions(d, TURN), pre)
    return PointViews(point=point, colour=colour, view_dir=d, normal=normal, xyz=normal.clone())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    candidates = {name: prefilter_environment(make_environment(name, ENV_HEIGHT)) for name in CAPTURE_ENVS}
    prefilter_s = time.perf_counter() - t0
    num_points, gaussians = demo_points()
    obs = scene(candidates[TRUTH], num_points)
    found = {}

    def estimate(coarse_points=None) -> None:
        found["light"] = estimate_light(obs, candidates, max_points=LIGHT_FIT.identify_points, coarse_points=coarse_points)

    def readout(fit, **search) -> None:  # fit_grid, or fit_grid_normal_search (light_fit's default)
        est = found["light"]
        grid = fit(obs, candidates[est.env], rotation_deg=est.rotation_deg, gain=est.gain, **search)
        read_posterior(grid, pool_neighbours(grid, obs.xyz))

    t_coarse = median_seconds(lambda: estimate(LIGHT_FIT.identify_coarse_points), repeats=args.repeats, warmup=0)
    coarse = found["light"]
    t_est = median_seconds(estimate, repeats=args.repeats, warmup=0)
    t_read = median_seconds(lambda: readout(fit_grid), repeats=args.repeats, warmup=0)
    t_search = median_seconds(lambda: readout(fit_grid_normal_search, rings_deg=LIGHT_FIT.normal_search_deg), repeats=args.repeats,
                              warmup=0)
    t_profile = median_seconds(lambda: readout(fit_grid_normal_search, rings_deg=LIGHT_FIT.normal_search_deg, profile=LIGHT_FIT.normal_profile),
                               repeats=args.repeats, warmup=0)
    est = found["light"]
    print(f"machine: {machine()}; one torch thread")
    print(f"candidates: {len(candidates)} procedural capture environments at {ENV_HEIGHT} rows, prefiltered "
          f"once per run in {prefilter_s:.1f} s")
    print(f"light estimate on {LIGHT_FIT.identify_points} points ({est.env} turned {est.rotation_deg:.1f} deg x{est.gain:.2f}; truth {TRUTH} "
          f"{TURN:.0f} deg x{GAIN}; margin {est.margin:.1f}): median {t_est:.2f} s")
    print(f"the same with the coarse search on {LIGHT_FIT.identify_coarse_points} of them (light_fit's; {coarse.env} turned "
          f"{coarse.rotation_deg:.1f} deg x{coarse.gain:.2f}): median {t_coarse:.2f} s")
    print(f"read-out of {num_points} points (light_fit's on the demo's median asset of {gaussians} Gaussians) x "
          f"{VIEWS} views (grid fit, 16-neighbour pooling, posterior): "
          f"median {t_read:.2f} s")
    print(f"the same with each normal searched in a cone (rings {LIGHT_FIT.normal_search_deg} degrees): median {t_search:.2f} s")
    print(f"each grid cell the best of the {LIGHT_FIT.normal_profile} best-ranked searched normals (light_fit's): median {t_profile:.2f} s")
    print(f"estimate + read-out: {t_est + t_read:.2f} s a scene without the normal search; light_fit's (coarse "
          f"search on {LIGHT_FIT.identify_coarse_points} points, profile over {LIGHT_FIT.normal_profile} searched normals) {t_coarse + t_profile:.2f} s "
          "(issue 66's target: <= 20 s)")


if __name__ == "__main__":
    main()
