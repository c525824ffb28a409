"""gspi-eval and gspi-table as a user runs them (subprocesses), on a fixture made by the tests."""
import json
import math
import subprocess
import sys


def _run(*args):
    proc = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_gspi_eval_then_gspi_table(sphere_dataset, tmp_path):
    from tests.fixtures import make_prediction
    pred = make_prediction(sphere_dataset, tmp_path / "pred", method="offset")
    out = _run("eval.cli", f"gt={sphere_dataset}", f"pred={pred}", f"out={tmp_path / 'ev'}",
               "progress=false", "eval.channels=[roughness,metallic]")
    assert "roughness" in out and "20.00" in out
    summary = json.loads((tmp_path / "ev" / "summary.json").read_text())
    assert set(summary) == {"roughness", "metallic"}
    assert summary["metallic"]["psnr"] == 10 * math.log10(12 * 65535.0**2)  # the cap, not inf
    assert summary["metallic"]["mae"] == 0.0 and summary["metallic"]["iou"] == 1.0
    meta = json.loads((tmp_path / "ev" / "eval_meta.json").read_text())
    assert meta["protocol_config"]["channels"] == ["roughness", "metallic"]
    assert (tmp_path / "ev" / ".hydra" / "config.yaml").is_file()
    rows = (tmp_path / "ev" / "per_view.csv").read_text().splitlines()
    assert rows[0] == "scene,view,channel,env,psnr,ssim,lpips,psnr_floored,mae,iou,psnr_metal"
    assert len(rows) == 1 + 2 * 3 * 2
    table = _run("eval.tables.cli", str(tmp_path / "ev"), f"out={tmp_path / 'tables'}")
    assert "| offset |" in table and (tmp_path / "tables" / "table1.tex").is_file()
    # the footer names every knob and the image counts
    for knob in ("gspi-decoupled v1 #", "split test", "albedo alignment none (scope scene)",
                 "PSNR over mask, MSE floor 1.94e-11 (cap 107.1 dB)", "SSIM window 11 valid over mask",
                 "LPIPS alex v0.1 masked_mean", "tone map aces+sRGB", "fills roughness 1.0",
                 "roughness 6 (0 at PSNR floor)", "metallic 6 (6 at PSNR floor"):
        assert knob in table, knob

    # the same predictions under an override that keeps the name: gspi-table refuses the mix
    _run("eval.cli", f"gt={sphere_dataset}", f"pred={pred}", f"out={tmp_path / 'ev2'}",
         "progress=false", "eval.channels=[roughness,metallic]", "eval.ssim.window=3")
    proc = subprocess.run([sys.executable, "-m", "eval.tables.cli", str(tmp_path / "ev"),
                           str(tmp_path / "ev2"), f"out={tmp_path / 't2'}"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "different protocols" in proc.stderr and "ssim.window: 11 != 3" in proc.stderr
    assert str(tmp_path / "ev2") in proc.stderr


def test_gspi_eval_reports_a_bad_override(sphere_dataset, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "eval.cli", f"gt={sphere_dataset}",
                           f"pred={sphere_dataset}", f"out={tmp_path}", "eval.albedo_alignment=mean"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0 and "albedo_alignment" in proc.stderr
    assert "allowed: none, scale, lstsq, per_channel, median_ratio" in proc.stderr


def test_method_alias_is_rewritten_to_method_name():
    from eval.common.argv import apply_aliases

    assert apply_aliases(["gt=a", "method=x", "out=o"], "gspi_eval") == ["gt=a", "method_name=x", "out=o"]
