"""gspi-reproduce: one paper table, from nothing to its committed scores and table, by one command.

    gspi-reproduce table=2 scale=cpu                  # rerun until it prints "done"
    gspi-reproduce table=2 scale=smoke                # the same steps at toy size (minutes; the test suite runs it)
    gspi-reproduce table=2 scale=cpu dry_run=true     # the steps left, with their commands and how far begun trainings got
    gspi-reproduce table=2 scale=cpu seeds=[0,1] variants=[full] recon=tiny   # any key of the table's config
    gspi-reproduce table=1 scale=cpu                  # Table 1 (the demo's sweep); table=3 the same for Table 3
    gspi-reproduce table=2 scale=cpu keep_state=true  # copy begun trainings' state to the repository (to commit)
    gspi-reproduce model=default scale=cpu            # the shipped default Stage II model, rebuilt from nothing

The table's config is conf/reproduce/table<N>_<scale>.yaml; ``scale`` is its size (smoke, cpu).
``model=<name>`` instead of ``table=N`` rebuilds a shipped model (conf/reproduce/model_<name>_<scale>.yaml:
the Table 2 training that made it, trained rather than taken from the repository).
``study=<name>`` adds a study's configs (``experiments/<name>/conf``, principle 10 of the style
guide: the product names no study) to the search path of this call and of every command it runs, so
a study's reproduce files (``<study conf>/reproduce/table<N>_<scale>.yaml``) and Stage 0 or Stage II
options are found beside the product's. ``data_root`` (default ``data`` under
the repository, or $GSPI_DATA_ROOT) holds what is not committed. Every step is skipped when its
output exists and resumes where it stopped, so a recipe longer than one session is the same
command run again (gspi/reproduce/plan.py). Ctrl-C loses nothing that finished.
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from eval.common.errors import EXIT_STATED, StatedError, one_line
from gspi.repo import REPO

log = logging.getLogger("gspi-reproduce")
ROOT_KEYS = ("data_root", "dry_run", "only", "keep_state")
ROOT_FLAGS = ("dry_run", "keep_state")  # true or false
STUDIES = REPO / "experiments"  # a study's configs: STUDIES / <study> / "conf" (its groups beside conf/'s)


class ReproduceError(StatedError, ValueError):
    """A bad gspi-reproduce call: names the key and what is expected."""


def conf_dirs(study: str | None) -> list[Path]:
    """The config folders of a call: conf/, then the study's (``study=<name>``)."""
    from eval.common.conf import CONF_DIR

    if study is None:
        return [Path(CONF_DIR)]
    conf = STUDIES / study / "conf"
    if not study or "/" in study or not conf.is_dir():
        known = ", ".join(sorted(p.parent.name for p in STUDIES.glob("*/conf"))) or "none"
        raise ReproduceError(f"study={study}: no {conf.relative_to(REPO)} folder; known: {known}")
    return [Path(CONF_DIR), conf]


def searchpath_override(study: str | None) -> list[str]:
    """The ``hydra.searchpath`` override that adds the study's configs (none without a study)."""
    return [f"hydra.searchpath=[file://{d}]" for d in conf_dirs(study)[1:]]


def available(study: str | None = None) -> list[str]:
    """The reproduce files a call can name: conf/reproduce's, and the study's with ``study=``."""
    return sorted({p.stem for d in conf_dirs(study) for pattern in ("table*_*.yaml", "model_*_*.yaml")
                   for p in (d / "reproduce").glob(pattern)})


def call_name(name: str) -> str:
    """How a call names the reproduce file ``name``: ``table=2 scale=cpu`` or ``model=default scale=cpu``."""
    what, scale = name.rsplit("_", 1)
    return f"model={what[len('model_'):]} scale={scale}" if what.startswith("model_") else f"table={what[5:]} scale={scale}"


def compose(argv: list[str]):
    """(table config, root config) of ``table=N scale=S [study=NAME] [key=value ...]``."""
    from hydra import compose as hydra_compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException
    from yaml import YAMLError

    from eval.common.conf import CONF_DIR

    pairs = {}
    for arg in argv:
        if "=" not in arg:
            raise ReproduceError(f"{arg!r}: expected key=value (e.g. table=2 scale=cpu)")
        key, value = arg.split("=", 1)
        pairs.setdefault(key, []).append(value)
    table, scale = pairs.pop("table", [None])[-1], pairs.pop("scale", [None])[-1]
    model = pairs.pop("model", [None])[-1]
    study = pairs.pop("study", [None])[-1]
    found = available(study)
    known = ", ".join(call_name(n) for n in found)
    if (table is None) == (model is None) or scale is None:
        raise ReproduceError(f"needs table=N (or model=NAME) and scale=S (e.g. table=2 scale=cpu); known: {known}")
    name, asked = (f"table{table}_{scale}", f"table={table}") if model is None else (f"model_{model}_{scale}", f"model={model}")
    if name not in found:
        files = " nor ".join(str(d.relative_to(REPO) / "reproduce" / f"{name}.yaml") for d in conf_dirs(study))
        raise ReproduceError(f"{asked} scale={scale}: no {files}; known: {known}")
    overrides = [f"{k if k in ROOT_KEYS else 'reproduce.' + k}={v}" for k, vs in pairs.items() for v in vs]
    searchpath = searchpath_override(study)
    try:
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            cfg = hydra_compose("gspi_reproduce", overrides=[*searchpath, f"reproduce={name}", *overrides])
        flags = {k: cfg[k] for k in ROOT_FLAGS}
    except (HydraException, OmegaConfBaseException, YAMLError) as exc:
        source = next(d for d in conf_dirs(study) if (d / "reproduce" / f"{name}.yaml").is_file())
        raise ReproduceError(f"{name}: {one_line(exc)} (keys: {source.relative_to(REPO)}/reproduce/{name}.yaml)") from exc
    bad = {k: v for k, v in flags.items() if not isinstance(v, bool)}
    if bad:
        raise ReproduceError(", ".join(f"{k}={v!r}" for k, v in bad.items()) + ": expected true or false")
    table_cfg = OmegaConf.to_container(cfg.reproduce, resolve=True)
    for key in ("recon_overrides", "train_overrides"):  # the commands it runs find the study's options too
        if key in table_cfg:
            table_cfg[key] = [*searchpath, *table_cfg[key]]
    return table_cfg, cfg


def plan(argv: list[str]):
    """The steps of a call, and its root config."""
    from gspi.reproduce.sweep_tables import sweep_table_steps
    from gspi.reproduce.table2 import table2_steps

    cfg, root_cfg = compose(argv)
    build = table2_steps if int(cfg["table"]) == 2 else sweep_table_steps
    return build(cfg, root=REPO), cfg, root_cfg


def main(argv: list[str] | None = None) -> int:
    from gspi.reproduce.plan import StepFailed, run_plan

    argv = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help", "help") for a in argv):
        from eval.common.cli_help import usage
        from eval.common.conf import CONF_DIR

        # its own keys (conf/gspi_reproduce.yaml), the tables it knows, then the module's examples
        tables = ", ".join(call_name(n) for n in available())
        print(usage(CONF_DIR, "gspi_reproduce", groups=False, hydra=False) +
              f"\n\ntables and models (table=N or model=NAME, and scale=S; any other key=value sets a key of "
              f"that config): {tables}\n\n" +
              "more examples:\n" + "\n".join("  " + line.strip() for line in __doc__.splitlines()
                                                if line.startswith("    gspi-reproduce ")))
        return 0
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    prog = "gspi-reproduce"
    try:
        steps, cfg, root_cfg = plan(argv)
        work = (REPO / cfg["work"]).resolve()
        if root_cfg.keep_state:
            from gspi.reproduce.table2 import keep_training_state

            if int(cfg["table"]) != 2 or not cfg.get("kept_state"):
                raise ReproduceError(f"table={cfg['table']} scale={cfg['scale']}: keep_state=true needs a "
                                     f"kept_state folder (a Table 2 config's key)")
            lines = keep_training_state(cfg, root=REPO)
            print("\n".join(lines) or "keep_state: no begun run to keep, no kept copy to remove")
            return 0
        only = list(root_cfg.only or [])
        ran = run_plan(steps, work / "reproduce.log", only=only, dry_run=bool(root_cfg.dry_run),
                       lanes=int(cfg.get("lanes", 1)))
    except (StatedError, StepFailed) as exc:
        print(f"{prog}: error: {one_line(exc)}", file=sys.stderr)
        return EXIT_STATED if isinstance(exc, StatedError) else 1
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; what finished is kept, rerun the same command to continue", file=sys.stderr)
        return 130
    if root_cfg.dry_run:
        print(f"{len(ran)} step(s) to do" if ran else "done: nothing left to do")
        return 0
    left = [s.name for s in steps if s.name not in ran and not s.is_done()]
    if left:  # only= left some out, or another call runs them
        print(f"{len(left)} step(s) left ({left[0]}, ...): left out by only= or run by another call "
              f"(its log: {work / 'reproduce.log'}); run the same command again to go on")
        return 0
    if cfg.get("model"):  # a shipped model rebuilt: where the checkpoint and its scores are
        from gspi.reproduce.table2 import run_name, runs_folder

        name = run_name(cfg["variants"][0], cfg["seeds"][0])
        print(f"done: model {cfg['model']} at scale {cfg['scale']}: {work / runs_folder(cfg) / name / 'checkpoint.pt'} "
              f"(its scores: {REPO / cfg['scores_dir'] / name / 'scores.json'})")
        return 0
    tables = REPO / cfg["tables_dir"]
    print(f"done: table {cfg['table']} at scale {cfg['scale']}: {tables}/table{cfg['table']}.md")
    return 0


def entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entry()
