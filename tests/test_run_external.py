"""An external system's outputs placed under `method.outputs` become a Table 1 row through
`gspi-run` (adapter import -> canonical predictions -> gspi-eval -> gspi-table), and a system
with no outputs configured is recorded as a failed job, not a row."""
from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

from eval.common.layout import read_scene, read_splits
from gspi.run.runner import run_job
from tests.adapter_fixtures import gt_maps, write_gs_ir
from tests.run_helpers import run_config



def test_external_outputs_give_a_table1_row(micro_dataset, tmp_path):
    name = read_splits(micro_dataset)["test"][0]
    scene = read_scene(micro_dataset / name)
    outputs = tmp_path / "gsir_outputs"
    write_gs_ir(outputs / name, gt_maps(scene), gamma=True)  # GS-IR's own layout, GT content
    sweep = tmp_path / "sweep"
    ok = run_job(run_config(micro_dataset, sweep / "gs_ir",
                            ["method=gs_ir", f"method.outputs={outputs}", "table=table1"]), reraise=True)
    assert ok["status"] == "complete"
    missing = run_job(run_config(micro_dataset, sweep / "r3dg", ["method=r3dg", "table=table1"]),
                      reraise=False)
    assert missing["status"] == "failed" and "outputs" in missing["error"]
    tables = tmp_path / "tables"
    proc = subprocess.run([sys.executable, "-m", "eval.tables.cli", str(sweep), f"out={tables}"],
                          cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    with open(tables / "table1.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 1, rows  # the failed job is listed under the table, not as a row
    row = rows[0]
    assert row["label"] == "GS-IR" and row["method"] == "gs_ir"
    # GT maps through GS-IR's layout (gamma, roughness remap, 8-bit panels) come back near exact
    assert float(row["psnr/albedo/mean"]) > 40 and float(row["psnr/roughness/mean"]) > 40
    # trained without --metallic: the channel is absent, shown as "--", not scored as zero
    assert row["psnr/metallic/n"] == "0" and row["psnr/metallic/mean"] == ""
    assert "| GS-IR |" in proc.stdout and "| -- |" in proc.stdout
    assert "failed job" in proc.stdout and "no outputs configured" in proc.stdout
