"""The one torch device of a gspi command: ``device=auto|cpu|cuda`` (issue #16).

Resolved once at start-up (``resolve_device``); every stage then receives a ``torch.device``
and tensors cross devices only at stage boundaries. ``auto`` picks CUDA when it is present, so
on a machine without a GPU ``auto`` and ``cpu`` are the same code path as before (the CPU
numbers do not move). ``cuda`` without CUDA is one clear error naming the key, not a
traceback from inside a stage.

The resolver itself is ``eval.common.device`` (gspi-eval must not import gspi, and one copy cannot
drift from another): this module is its name on the gspi side.
"""
from __future__ import annotations

from eval.common.device import CHOICES, DeviceError, resolve_device

__all__ = ["CHOICES", "DeviceError", "resolve_device"]
