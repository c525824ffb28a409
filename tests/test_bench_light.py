"""benchmarks/bench_light.py times light_fit's read at the size light_fit reads on the demo: its
points come from the shipped config and the shipped demo assets, read when the benchmark runs."""
from __future__ import annotations

import statistics

from benchmarks.bench_light import DEMO_ASSETS, demo_points
from gspi.gaussians.ply import read_ply


def test_the_benchmark_reads_light_fits_points_on_the_demos_median_asset():
    counts = [read_ply(p).num_gaussians for p in sorted(DEMO_ASSETS.glob("*/point_cloud.ply"))]
    assert len(counts) == 4
    points, gaussians = demo_points()
    assert gaussians == int(statistics.median(counts))
    assert points == min(20000, round(2 * gaussians))  # conf/method/light_fit.yaml: 20 000, 2 per Gaussian
