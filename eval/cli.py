"""`gspi-eval`: score a prediction folder against a ground-truth dataset.

    gspi-eval gt=data/small pred=runs/x/predictions out=runs/x/eval
    gspi-eval gt=data/small pred=data/small out=/tmp/oracle          # the oracle (PSNR cap 107.12)
    gspi-eval gt=... pred=... out=... eval.albedo_alignment=lstsq eval.lpips.mode=composite
    gspi-eval gt=... pred=... out=... eval=stanford_orb               # a preset: stanford_orb,
                                                      # tensoir, gs_ir, paper, aligned_clamp
    gspi-eval gt=... pred=... out=... device=auto     # score on CUDA when present (default cpu)

Paths may hold any character: `pred=runs/method=gspi/predictions` (a sweep's job folder),
spaces, quotes, commas or non-ASCII are quoted for Hydra's grammar (eval/common/argv.py); in a
key other than gt/pred/out, quote by hand: 'key="a=b"'. Zero scored images is an error.

Writes <out>/per_view.csv, <out>/summary.json, <out>/eval_meta.json and <out>/.hydra/.
"""
from __future__ import annotations

import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from eval.common.cli_entry import hydra_cli
from eval.config import register_configs, validate_protocol
from eval.common.device import resolve_device
from eval.evaluate import evaluate
from eval.records.eval_folder import SUMMARY_NAME, clear_result, format_summary, write_result

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict:
    """Evaluate `cfg.pred` against `cfg.gt` under protocol `cfg.eval`; returns the summary."""
    validate_protocol(cfg.eval)
    device = resolve_device(cfg.get("device", "cpu"))  # device=cuda without CUDA fails here
    clear_result(Path(cfg.out))  # an old summary.json must not outlive this run's .hydra/
    result = evaluate(Path(cfg.gt), Path(cfg.pred), cfg.eval, method=cfg.get("method_name"),
                      progress=bool(cfg.get("progress", True)), device=device)
    write_result(Path(cfg.out), result, OmegaConf.to_container(cfg.eval, resolve=True))
    text = format_summary(result)
    print(text)
    log.info("wrote %s", Path(cfg.out) / SUMMARY_NAME)
    return result.summary


register_configs()


# `method=<name>` is an alias of the key `method_name=<name>`: conf/method/ is a config group
# (the methods gspi-run can run), so Hydra would read `method=...` as a group override.


PATH_KEYS = ("gt", "pred", "out")  # quoted for Hydra when they hold = , ' spaces or non-ASCII (eval/common/argv.py)


def main() -> None:
    hydra_cli(run, "gspi_eval", path_keys=PATH_KEYS)()


if __name__ == "__main__":
    main()
