"""`gspi-eval`: score a prediction folder against a ground-truth dataset.

    gspi-eval gt=data/small pred=runs/x/predictions out=runs/x/eval
    gspi-eval gt=data/small pred=data/small out=/tmp/oracle          # the oracle (PSNR inf)
    gspi-eval gt=... pred=... out=... eval.albedo_alignment=per_channel eval.lpips.mode=composite
    gspi-eval gt=... pred=... out=... eval=stanford_orb_like          # another protocol file

Writes <out>/per_view.csv, <out>/summary.json, <out>/eval_meta.json and <out>/.hydra/.
"""
from __future__ import annotations

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from eval.config import CONF_DIR, register_configs, validate_protocol
from eval.evaluate import evaluate
from eval.report import format_summary, write_result

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict:
    """Evaluate `cfg.pred` against `cfg.gt` under protocol `cfg.eval`; returns the summary."""
    validate_protocol(cfg.eval)
    result = evaluate(Path(cfg.gt), Path(cfg.pred), cfg.eval, method=cfg.get("method"),
                      progress=bool(cfg.get("progress", True)))
    write_result(Path(cfg.out), result, OmegaConf.to_container(cfg.eval, resolve=True))
    text = format_summary(result)
    print(text)
    log.info("wrote %s", Path(cfg.out) / "summary.json")
    return result.summary


register_configs()


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="gspi_eval")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
