"""The study's tables (results/*.md) are generated from its committed scores (log/, results/scores/)
and the product's (results/table2/cpu/, results/table1/cpu/), like the product's result tables;
every reproduce file of the study composes and plans through gspi-reproduce study=view_dependence."""
from pathlib import Path

import pytest

CONF = Path(__file__).resolve().parents[1] / "conf" / "reproduce"


def test_committed_probe_tables_equal_the_generated_ones():
    from experiments.view_dependence.probe_tables import main

    assert main(["--check"]) == 0


@pytest.mark.parametrize("name", sorted(p.stem for p in CONF.glob("table*_*.yaml")))
def test_every_reproduce_file_of_the_study_dry_runs(name, tmp_path, capsys):
    from gspi.cli import reproduce as cli

    table, scale = name.removeprefix("table").split("_", 1)
    argv = ["study=view_dependence", f"table={table}", f"scale={scale}", f"data_root={tmp_path}", "dry_run=true"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert "step(s) to do" in out or "nothing left to do" in out
    assert not any(tmp_path.iterdir())  # a dry run writes nothing


def test_the_study_runs_find_its_stage0_configs(tmp_path):
    """The commands a study call runs carry the study's config folder (recon=fast_view_mild is here)."""
    from gspi.cli import reproduce as cli

    steps, cfg, _ = cli.plan(["study=view_dependence", "table=2", "scale=cpu_view", "seeds=[7]", f"data_root={tmp_path}"])
    stage0 = next(s for s in steps if s.name.startswith("stage 0"))
    assert any(str(a).startswith("hydra.searchpath=") and "view_dependence" in str(a) for a in stage0.command)
    assert "hydra.searchpath" not in stage0.marker_text()  # where configs are found is no part of the step
