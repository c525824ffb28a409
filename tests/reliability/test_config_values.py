"""Class 6, config values: every value is checked for type and range when the CLI starts
(gspi/strict_config.py, eval.config.validate_protocol), and the error names the key and what is
allowed; before the fix these crashed later (ZeroDivisionError), wrote an untrained asset
(`recon.iterations=-1`) or silently changed SSIM/LPIPS (`eval.background=7`)."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.reliability.helpers import EVAL_FAST, assert_fails_naming, run_cli
from tests.run_helpers import MICRO_DATA, TINY_RUN

# override -> what the message must name (the key, and the allowed range or type)
RUN_CASES = {
    "stage1.image_size=0": ("stage1.image_size", "[8, 8192]"),
    "stage1.image_size=abc": ("stage1.image_size", "an integer"),
    "stage3.iterations=abc": ("stage3.iterations", "an integer"),
    "stage3.iterations=2.5": ("stage3.iterations", "an integer"),
    "recon.iterations=-1": ("recon.iterations", ">= 1"),
    "seed=abc": ("seed", "an integer"),
    "threads=abc": ("threads", "an integer"),
    "threads=0": ("threads", "[1, 1024]"),
    "eval.background=7": ("eval.background", "[0, 1]"),
    "eval.channels=[]": ("eval.channels", "at least one"),
    "stage1.alpha_threshold=2": ("stage1.alpha_threshold", "[0.0, 1.0]"),
    "stage3.backend=cuda": ("stage3.backend", "one of"),
    "split=Test": ("split", "one of"),
}


@pytest.fixture(scope="module")
def run_cfg(micro_dataset, tmp_path_factory) -> dict:
    """The resolved gspi-run config of a tiny job, composed once (Hydra composes in ~1 s)."""
    from tests.run_helpers import run_config

    return run_config(micro_dataset, tmp_path_factory.mktemp("cfg") / "run", ["method=no_decomposition"])


def _with_override(cfg: dict, override: str) -> dict:
    """``cfg`` with one command-line override applied as Hydra parses its value."""
    import copy

    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_override(override)
    out = copy.deepcopy(cfg)
    *parents, leaf = parsed.key_or_group.split(".")
    node = out
    for key in parents:
        node = node[key]
    node[leaf] = parsed.value()
    return out


@pytest.mark.parametrize("override", sorted(RUN_CASES))
def test_run_config_check_refuses_a_bad_value(run_cfg, override):
    """The start-up check gspi-run calls (gspi.run.config_check) on each bad value."""
    from gspi.run.config_check import check_run_config

    with pytest.raises(ValueError) as info:
        check_run_config(_with_override(run_cfg, override))
    assert all(name in str(info.value) for name in RUN_CASES[override]), str(info.value)


@pytest.mark.parametrize("override", ["recon.iterations=-1", "stage3.iterations=2.5", "seed=abc", "eval.background=7"])
def test_gspi_run_refuses_a_bad_value_at_start_up(micro_dataset, tmp_path, override):
    """Through the CLI: exit 1 at start-up, the key named, no record and no prediction written."""
    from gspi.cli.run import main

    out = tmp_path / "run"
    code, text = run_cli(main, [f"data={micro_dataset}", f"out={out}", *TINY_RUN, "method=no_decomposition", override])
    assert_fails_naming(code, text, *RUN_CASES[override])
    assert not (out / "result.json").exists() and not (out / "predictions").exists()


DATA_CASES = {"data.image_size=0": ("data.image_size", "[8, 8192]"),
              "data.supersample=abc": ("data.supersample", "an integer"),
              "seed=abc": ("seed", "an integer"), "threads=abc": ("data.threads", "an integer")}


@pytest.mark.parametrize("override", sorted(DATA_CASES))
def test_gspi_data_refuses_a_bad_value_at_start_up(tmp_path, override):
    from gspi.cli.data import main

    code, text = run_cli(main, ["preset=tiny", f"out={tmp_path / 'd'}", *MICRO_DATA, override])
    assert_fails_naming(code, text, *DATA_CASES[override])
    assert not list((tmp_path / "d").glob("s0*"))


@pytest.mark.parametrize("override,names", [("threads=abc", ("threads", "an integer")),
                                            ("seed=-1", ("seed", ">= 0"))])
def test_gspi_train_refuses_a_bad_value_at_start_up(micro_dataset, tmp_path, override, names):
    from gspi.cli.train import main

    code, text = run_cli(main, [f"data={micro_dataset}", f"out={tmp_path / 's2'}", "stage2=tiny", override])
    assert_fails_naming(code, text, *names)
    assert not (tmp_path / "s2" / "checkpoint.pt").exists()


@pytest.mark.parametrize("override,names", [("eval.background=7", ("eval.background", "[0, 1]")),
                                            ("eval.albedo_alignment=mean", ("eval.albedo_alignment", "allowed"))])
def test_gspi_eval_refuses_a_bad_value_at_start_up(workspace, override, names):
    from eval.cli import main

    code, text = run_cli(main, [f"gt={workspace / 'gt'}", f"pred={workspace / 'pred'}", f"out={workspace / 'ev'}",
                                *EVAL_FAST, override])
    assert_fails_naming(code, text, *names)
    assert not (workspace / "ev" / "summary.json").exists()


def test_typo_in_a_key_names_the_key(micro_dataset, tmp_path):
    """Already handled well before the fix (kept as a case): an unknown key is refused."""
    from gspi.cli.run import main

    code, text = run_cli(main, [f"data={micro_dataset}", f"out={tmp_path / 'run'}", *TINY_RUN,
                                "method=no_decomposition", "stage3.iteratoins=5"])
    assert code != 0 and "stage3.iteratoins" in text


SHIPPED = [f"{g}/{p.stem}" for g in ("recon", "stage1", "stage3", "eval", "ablation", "experiment")
           for p in sorted((Path(__file__).resolve().parents[2] / "conf" / g).glob("*.yaml"))]


@pytest.mark.parametrize("option", SHIPPED)
def test_the_shipped_configs_pass_the_checks(run_cfg, option):
    """Every option we ship passes the start-up check (the ranges refuse nothing we use).
    Applied onto the composed default (a Hydra compose per option would take ~1 s each)."""
    from omegaconf import OmegaConf

    from gspi.run.config_check import check_run_config

    group = option.split("/")[0]
    path = Path(__file__).resolve().parents[2] / "conf" / f"{option}.yaml"
    values = OmegaConf.to_container(OmegaConf.load(path))
    values = {k: v for k, v in (values or {}).items() if k not in ("defaults", "hydra")}
    is_global = "@package _global_" in path.read_text().split("\n", 3)[0]
    base = OmegaConf.create(run_cfg)
    merged = OmegaConf.merge(base, values if is_global else {group: values})
    cfg = OmegaConf.to_container(merged, resolve=False)
    cfg.pop("experiment_name", None)
    check_run_config(cfg)
