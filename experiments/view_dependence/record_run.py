"""One end-to-end ``gspi-run``'s per-scene scores as a committed probe record (issue 52):
``experiments/view_dependence/log/<probe>/demo_<name>.json``, which ``probe_tables`` reads into its end-to-end tables.

    python -m experiments.view_dependence.record_run RUN OUT --recon fast_view_mild \
        --checkpoint '<the model>' --command '<the gspi-run line>' --machine '<what else ran>'

The record holds the run's protocol and each scene's scores from its ``eval/eval_meta.json``
(gspi-eval's own file, unchanged), with the command that made it and the machine's load: what a
reader needs to rerun it; never a path of this machine.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def run_record(run: Path, *, recon: str, checkpoint: str, command: str, machine: str) -> dict:
    """The record of a finished gspi-run folder; a clear error when it did not finish scoring."""
    meta_path = run / "eval" / "eval_meta.json"
    if not meta_path.is_file():
        raise SystemExit(f"{meta_path}: missing; {run} is not a finished gspi-run (no gspi-eval scores)")
    meta = json.loads(meta_path.read_text())
    if not meta.get("per_scene"):
        raise SystemExit(f"{meta_path}: no per-scene scores")
    return {"checkpoint": checkpoint, "command": command, "machine": machine, "per_scene": meta["per_scene"],
            "protocol": meta["protocol"], "recon": recon}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--recon", required=True)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--command", required=True)
    parser.add_argument("--machine", required=True)
    args = parser.parse_args(argv)
    record = run_record(args.run, recon=args.recon, checkpoint=args.checkpoint, command=args.command,
                        machine=args.machine)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
