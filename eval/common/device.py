"""The one torch device of a command: ``device=auto|cpu|cuda`` (issue #16).

Resolved once at start-up (``resolve_device``); the work then receives a ``torch.device`` and
tensors cross devices only at boundaries (files are read and written on the CPU). ``auto``
picks CUDA when it is present, so on a machine without a GPU ``auto`` and ``cpu`` are the same
code path as before (the CPU numbers do not move). ``cuda`` without CUDA is one clear error
naming the key, not a traceback from inside the work.

It lives in eval/ (the lowest floor: eval imports nothing of gspi) so that gspi-eval and the
gspi commands share one resolver; ``gspi.device`` re-exports it.
"""
from __future__ import annotations

import torch

from eval.common.errors import StatedError

CHOICES = ("auto", "cpu", "cuda")


class DeviceError(StatedError, ValueError):
    """A ``device`` setting that cannot be honoured on this machine."""


def resolve_device(value, *, key: str = "device") -> torch.device:
    """``auto`` -> cuda if available else cpu; ``cpu``; ``cuda`` or ``cuda:N`` (checked here)."""
    text = str(value).strip().lower() if value is not None else "auto"
    base, _, index = text.partition(":")
    if base not in CHOICES or (index and (base != "cuda" or not index.isdigit())):
        raise DeviceError(f"{key}={value!r}: expected one of {', '.join(CHOICES)} (or cuda:N)")
    if base == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if base == "cuda":
        if not torch.cuda.is_available():
            raise DeviceError(f"{key}={value}: CUDA is not available on this machine "
                              f"(torch {torch.__version__}, built with CUDA {torch.version.cuda}); "
                              f"use {key}=cpu or {key}=auto")
        if index and int(index) >= torch.cuda.device_count():
            raise DeviceError(f"{key}={value}: only {torch.cuda.device_count()} CUDA device(s) here")
    return torch.device(text)
