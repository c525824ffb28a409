"""Protocol sensitivity report: deltas against the reference convention and ranking changes."""
import math

import pandas as pd
import pytest
from omegaconf import OmegaConf

from eval.sensitivity import ranking, run, sensitivity


def _scores(rows):
    return pd.DataFrame(rows, columns=["convention", "method", "channel", "metric", "value"])


def test_deltas_and_a_flipped_ranking_by_hand():
    scores = _scores([
        ("default", "A", "albedo", "psnr", 20.0), ("default", "B", "albedo", "psnr", 18.0),
        ("default", "A", "albedo", "lpips", 30.0), ("default", "B", "albedo", "lpips", 40.0),
        ("knob", "A", "albedo", "psnr", 21.0), ("knob", "B", "albedo", "psnr", 22.5),
        ("knob", "A", "albedo", "lpips", 3.0), ("knob", "B", "albedo", "lpips", 5.0)])
    deltas, ranks = sensitivity(scores, "default")
    assert deltas.loc["knob", ("psnr", "albedo", "A")] == pytest.approx(1.0)
    assert deltas.loc["knob", ("psnr", "albedo", "B")] == pytest.approx(4.5)
    assert deltas.loc["knob", ("lpips", "albedo", "B")] == pytest.approx(-35.0)
    assert ranks.loc["knob", ("psnr", "albedo")] == "B > A"       # flipped
    assert ranks.loc["knob", ("lpips", "albedo")] == "kept"       # lower is better: A first
    assert ranks.loc["default", ("psnr", "albedo")] == "kept"


def test_ranking_direction():
    values = pd.Series({"A": 0.2, "B": 0.1})
    assert ranking(values, "lpips") == ("B", "A") and ranking(values, "psnr") == ("A", "B")


def test_run_on_the_fixture_writes_the_report(sphere_dataset, tmp_path):
    from tests.fixtures import make_prediction

    good = make_prediction(sphere_dataset, tmp_path / "good", channels=("roughness",))
    bad = make_prediction(sphere_dataset, tmp_path / "bad", channels=("roughness",),
                          roughness_offset=13108 / 65535)
    cfg = OmegaConf.create({
        "gt": str(sphere_dataset), "out": str(tmp_path / "out"),
        "methods": {"good": str(good), "bad": str(bad)},
        "conventions": {"default": ["eval.channels=[roughness]"],
                        "image": ["eval.channels=[roughness]", "eval.psnr.region=image"]}})
    scores = run(cfg)
    md = (tmp_path / "out" / "sensitivity.md").read_text()
    assert "| image |" in md and "Reference convention: `default`" in md
    psnr = scores[(scores["metric"] == "psnr")].set_index(["convention", "method"])["value"]
    # a constant roughness offset d: -20 log10(d) in the mask; the image region adds
    # 10 log10(1 / f) for the foreground fraction f, the same for both methods
    assert psnr["default", "good"] == pytest.approx(-20 * math.log10(6554 / 65535), abs=1e-6)
    assert psnr["default", "bad"] == pytest.approx(-20 * math.log10(13108 / 65535), abs=1e-6)
    lift = psnr["image", "good"] - psnr["default", "good"]
    assert lift > 0 and psnr["image", "bad"] - psnr["default", "bad"] == pytest.approx(lift, abs=1e-6)
