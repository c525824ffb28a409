"""Protocol sensitivity: how each protocol knob moves each number, and whether the ranking of
methods survives it (docs/PROTOCOL.md, "Sensitivity").

    python -m eval.sensitivity gt=demo_out/data out=/tmp/sens \
        'methods={gspi: runs/gspi/predictions, no_decomposition: runs/nd/predictions}'

`conf/gspi_sensitivity.yaml` lists the conventions: a label and the `gspi-eval` overrides that
define it (one knob changed from the default each, then the field's presets). Every method is
scored under every convention by `eval.evaluate`; the report gives each number's change from
the first convention (the reference), and for each (channel, metric) whether the order of the
methods stays the same.
"""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from eval.evaluate import EXTRA_METRICS, METRICS, evaluate
from eval.common.atomic import write_text_atomic

HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "lpips": False, "psnr_h": True, "mae": False,
                    "iou": True, "psnr_metal": True}
DISPLAY = {"psnr": 1.0, "ssim": 100.0, "lpips": 100.0, "psnr_h": 1.0, "mae": 100.0, "iou": 100.0, "psnr_metal": 1.0}


def compose_protocol(overrides: list[str]):
    """The resolved, validated `cfg.eval` of `gspi-eval` with these overrides."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from eval.common.conf import CONF_DIR

    from eval.config import register_configs, validate_protocol

    register_configs()
    args = dict(config_name="gspi_eval", overrides=["gt=_", "pred=_", "out=_", *overrides])
    if GlobalHydra.instance().is_initialized():  # inside this module's CLI (hydra_cli, same conf/)
        cfg = compose(**args)
    else:
        with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
            cfg = compose(**args)
    validate_protocol(cfg.eval)
    return cfg.eval


def score_all(gt: Path, methods: dict[str, Path], conventions: dict[str, list[str]],
              nets: dict | None = None) -> pd.DataFrame:
    """Long frame: convention, method, channel, metric, value (display units)."""
    from eval.lpips.net import load_lpips

    nets = {} if nets is None else nets
    rows = []
    for label, overrides in conventions.items():
        protocol = compose_protocol(list(overrides))
        net = nets.setdefault(protocol.lpips.net, None) or load_lpips(protocol.lpips.net)
        nets[protocol.lpips.net] = net
        for method, pred in methods.items():
            summary = evaluate(gt, pred, protocol, net=net, method=method).summary
            for channel, values in summary.items():
                for metric in (*METRICS, *EXTRA_METRICS):
                    if metric in values:
                        rows.append({"convention": label, "method": method, "channel": channel,
                                     "metric": metric, "value": DISPLAY[metric] * values[metric]})
    return pd.DataFrame(rows, columns=["convention", "method", "channel", "metric", "value"])


def ranking(values: pd.Series, metric: str) -> tuple[str, ...]:
    """Methods best first (ties keep the input order)."""
    return tuple(values.sort_values(ascending=not HIGHER_IS_BETTER[metric], kind="stable").index)


def sensitivity(scores: pd.DataFrame, reference: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(deltas, rankings) of a `score_all` frame against the `reference` convention.

    deltas: convention x (metric, channel, method) change from the reference.
    rankings: convention x (metric, channel) -> "kept" or the new order, best first.
    """
    wide = scores.pivot_table(index="convention", columns=["metric", "channel", "method"],
                              values="value", sort=False)
    deltas = wide - wide.loc[reference]
    ranks = {}
    for (metric, channel), block in wide.T.groupby(level=["metric", "channel"], sort=False):
        ref_values = block[reference].droplevel([0, 1]).dropna()
        ref_order = ranking(ref_values, metric) if len(ref_values) else None
        for conv in wide.index:
            col = block[conv].droplevel([0, 1]).dropna()
            if col.empty:
                continue
            order = ranking(col, metric)
            ranks.setdefault(conv, {})[(metric, channel)] = \
                "kept" if order == ref_order else " > ".join(order)
            if ref_order is None:  # nothing to compare with: the order itself
                ranks[conv][(metric, channel)] = "order " + " > ".join(order)
    return deltas, pd.DataFrame(ranks).T.reindex(wide.index)


def to_markdown(scores: pd.DataFrame, deltas: pd.DataFrame, ranks: pd.DataFrame,
                conventions: dict[str, list[str]], reference: str) -> str:
    """One table per metric: rows conventions, columns method/channel; reference row absolute."""
    lines = [f"Reference convention: `{reference}` (absolute values); other rows: change from it "
             "(\"=x\": absolute, where the reference has no such number). PSNR/PSNR-H in dB, "
             "SSIM, LPIPS, MAE and IoU in %. Ranking: \"kept\", or the new order (best first) "
             "of each channel whose order of methods differs from the reference's.", ""]
    for metric in [m for m in HIGHER_IS_BETTER if m in deltas.columns.get_level_values(0)]:
        block = deltas[metric]
        cols = list(block.columns)
        lines += [f"#### {metric}", "",
                  "| convention | " + " | ".join(f"{m} {c}" for c, m in cols) + " | ranking |",
                  "|---|" + "---|" * (len(cols) + 1)]
        for conv in block.index:
            cells = [_cell(scores, conv, reference, metric, c, m, block.loc[conv, (c, m)])
                     for c, m in cols]
            if all(cell == "--" for cell in cells):
                continue  # this convention has no such number
            changed = [f"{c}: {ranks.loc[conv, (metric, c)]}" for c in dict.fromkeys(c for c, _ in cols)
                       if (metric, c) in ranks.columns and isinstance(ranks.loc[conv, (metric, c)], str)
                       and ranks.loc[conv, (metric, c)] != "kept"]
            lines.append(f"| {conv} | " + " | ".join(cells) + " | "
                         + ("; ".join(changed) if changed else "kept") + " |")
        lines.append("")
    lines += ["Conventions (gspi-eval overrides):", ""]
    lines += [f"- `{label}`: {' '.join(ov) if ov else '(default)'}" for label, ov in conventions.items()]
    return "\n".join(lines) + "\n"


def _cell(scores, conv, reference, metric, channel, method, delta) -> str:
    """Absolute value on the reference row; elsewhere the change, or "=value" (absolute)
    where the reference has no such number (e.g. PSNR-H only in the stanford_orb preset)."""
    value = scores_value(scores, conv, metric, channel, method)
    if pd.isna(value):
        return "--"
    if conv == reference:
        return f"{value:.2f}"
    return f"={value:.2f}" if pd.isna(delta) else f"{delta:+.2f}"


def scores_value(scores: pd.DataFrame, conv: str, metric: str, channel: str, method: str) -> float:
    sel = scores[(scores["convention"] == conv) & (scores["metric"] == metric)
                 & (scores["channel"] == channel) & (scores["method"] == method)]
    return float(sel["value"].iloc[0]) if len(sel) else float("nan")


def run(cfg) -> pd.DataFrame:
    conventions = {str(k): [str(o) for o in v] for k, v in cfg.conventions.items()}
    methods = {str(k): Path(str(v)) for k, v in (cfg.methods or {}).items()}
    if not methods:
        raise ValueError("give the methods to compare: 'methods={name: prediction dir, ...}'")
    reference = next(iter(conventions))
    scores = score_all(Path(cfg.gt), methods, conventions)
    deltas, ranks = sensitivity(scores, reference)
    out = Path(cfg.out)
    write_text_atomic(out / "sensitivity_scores.csv", scores.to_csv(index=False))
    write_text_atomic(out / "sensitivity.md", to_markdown(scores, deltas, ranks, conventions, reference))
    write_text_atomic(out / "sensitivity_conventions.json", json.dumps(conventions, indent=2))
    print((out / "sensitivity.md").read_text())
    return scores


def main() -> None:
    """`python -m eval.sensitivity gt=... out=... 'methods={...}'`, through the one CLI door."""
    from eval.common.cli_entry import hydra_cli

    hydra_cli(run, "gspi_sensitivity", path_keys=("gt", "out"))()


if __name__ == "__main__":
    main()
