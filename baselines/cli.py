"""`gspi-export system=` / `gspi-import`: move a canonical scene to an external system and back
(gspi-export's door is gspi/cli/export.py: ``asset=`` is the GLB export, ``system=`` lands here).

    gspi-export system=gs_ir scene=data/small/s002_multipart_ceramic out=exports/gs_ir/s002
    gspi-export system=gs_ir scene=... out=... run=true method.checkout=~/src/GS-IR  # + train
    gspi-export system=lumigauss scene=... out=... model=runs/lumigauss/s002
    gspi-export system=materialanything scene=... out=... method.mesh=meshes/   # <scene>.obj
    gspi-import system=gs_ir src=exports/gs_ir/s002/model scene=data/small/s002_... out=preds/gs_ir
    gspi-import system=gs_ir src=... scene=... out=... method.gamma=false runtime_s=5400
    gspi-import system=irgs src=... scene=... out=... split=lattice   # the lattice (train) views

`system=<name>` is an alias of the config-group override `method=<name>` (conf/method/);
adapter options are overridden as `method.<option>=<value>`. `gspi-export` writes the system's
input folder to `out`, prints the commands that train the system and render its test views into
`model` (default `<out>/model`) and saves them as `<out>/commands.sh`; with `run=true` it runs
them in `method.checkout` and times them (`<model>/gspi_runtime.json`, read back by
`gspi-import`). `gspi-import` writes `<out>/<scene name>/<split>/<view id>/*.png` + `meta.json` (`split=test`, or
`lattice` = `train`, the lattice views, where the system's commands rendered them).
Configs: conf/gspi_export.yaml, conf/gspi_import.yaml. The working directory never changes.
"""
from __future__ import annotations

import logging
import shlex
import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from baselines.adapter import as_dict, get_adapter
from eval.common.cli_entry import hydra_cli

log = logging.getLogger(__name__)
# Absolute, as gspi/cli/*.py: a relative path would resolve as a Python package when the module
# is imported by a console script.


def model_dir(cfg: DictConfig) -> Path:
    return Path(cfg.model) if cfg.get("model") else Path(cfg.out) / "model"


def run_export(cfg: DictConfig) -> dict:
    """Export `cfg.scene` for system `cfg.method.name`; print (and with `run`, run) commands."""
    method = as_dict(cfg.method)
    adapter = get_adapter(str(method["name"]))
    out = adapter.export(Path(cfg.scene), Path(cfg.out), method)
    model = model_dir(cfg)
    argvs = adapter.commands(out, model, method)
    checkout = method.get("checkout") or "<checkout>"
    script = ["#!/bin/sh", f"# {method['name']}: train and render test views "
              f"(repo {method.get('repo', {}).get('url')})", "set -e",
              f"cd {shlex.quote(str(checkout))}", *(shlex.join(a) for a in argvs)]
    (out / "commands.sh").write_text("\n".join(script) + "\n")
    runtime = adapter.run(out, model, method, dry_run=not bool(cfg.get("run", False)))
    return {"system": method["name"], "export": str(out), "model": str(model),
            "commands": argvs, "runtime_s": runtime}


def as_runtime(value):
    """`runtime_s=` of the command line: a number (total seconds) or {geometry, material}."""
    return as_dict(value) if isinstance(value, DictConfig) else float(value)


def run_import(cfg: DictConfig) -> dict:
    """Import the outputs in `cfg.src` of system `cfg.method.name` into `cfg.out`."""
    from eval.protocol_id import ALIASES

    method = as_dict(cfg.method)
    adapter = get_adapter(str(method["name"]))
    runtime = cfg.get("runtime_s")
    split = str(cfg.get("split", "test"))
    allowed = (*adapter.rendered_splits, *(a for a, s in ALIASES["split"].items() if s in adapter.rendered_splits))
    if split not in allowed:
        raise ValueError(f"split={split!r}; allowed for {method['name']}: {', '.join(allowed)}")
    scene_out = adapter.import_outputs(Path(cfg.src), Path(cfg.scene), Path(cfg.out), method,
                                       runtime_s=None if runtime is None else as_runtime(runtime),
                                       split=ALIASES["split"].get(split, split))
    log.info("wrote %s", scene_out)
    return {"system": method["name"], "prediction": str(scene_out)}


def _run_import_and_print(cfg: DictConfig) -> dict:
    record = run_import(cfg)
    print(OmegaConf.to_yaml(record), end="")
    return record


PATH_KEYS = ("src", "scene", "out")  # quoted for Hydra's grammar (eval/common/argv.py)
export_system_main = hydra_cli(run_export, "gspi_export", path_keys=PATH_KEYS)
import_main = hydra_cli(_run_import_and_print, "gspi_import", path_keys=PATH_KEYS)


if __name__ == "__main__":  # python -m baselines.cli {export|import} system=... ...
    command = sys.argv.pop(1) if len(sys.argv) > 1 else ""
    if command not in ("export", "import"):
        sys.exit("usage: python -m baselines.cli {export|import} system=<name> ...")
    export_system_main() if command == "export" else import_main()
