"""The repository root, resolved once: where the product's committed files live (``conf/``,
``checkpoints/``, ``results/``, ``docs/``) and against which stored paths are made relative."""
from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
