"""Run-file logging of Stage II training: ``metrics.jsonl`` (one ``{"step", "key", "value"}``
row per scalar, the source of truth) and ``loss_curve.png`` drawn from it."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np


class JsonlMetrics:
    """Appends scalars to ``<out>/metrics.jsonl``; ``truncate_after(step)`` drops rows logged after
    the checkpoint a run resumes from, so a resumed run's file equals an uninterrupted one's."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def log(self, step: int, values: dict[str, float]) -> None:
        with self.path.open("a") as f:
            for key, value in values.items():
                f.write(json.dumps({"step": int(step), "key": key, "value": float(value)}) + "\n")

    def rows(self) -> list[dict]:
        if not self.path.is_file():
            return []
        return [json.loads(line) for line in self.path.read_text().splitlines() if line.strip()]

    def truncate_after(self, step: int) -> None:
        if self.path.is_file():
            kept = [r for r in self.rows() if r["step"] <= step]
            self.path.write_text("".join(json.dumps(r) + "\n" for r in kept))

    def series(self, key: str) -> tuple[np.ndarray, np.ndarray]:
        rows = [r for r in self.rows() if r["key"] == key]
        return np.array([r["step"] for r in rows]), np.array([r["value"] for r in rows], dtype=np.float64)


def smooth(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average (window clipped at the start)."""
    if len(values) == 0:
        return values
    c = np.cumsum(np.insert(values, 0, 0.0))
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return (c[idx] - c[lo]) / (idx - lo)


def plot_loss_curve(metrics: JsonlMetrics, png_path: str | Path, *, key: str = "stage2/train/loss",
                    title: str = "Stage II training loss") -> Path | None:
    """Per-step loss (faint) and its moving average; None when matplotlib is not installed."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    steps, values = metrics.series(key)
    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=100)
    ax.plot(steps, values, color="tab:blue", alpha=0.25, lw=0.6, label="per step")
    window = max(1, len(values) // 50)
    ax.plot(steps, smooth(values, window), color="tab:blue", lw=1.5, label=f"moving mean ({window})")
    ax.set_xlabel("step")
    ax.set_ylabel("Min-SNR eps loss")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png_path)
    plt.close(fig)
    return Path(png_path)
