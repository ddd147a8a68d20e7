"""Pick the torch device from a spec string: ``auto`` (CUDA when present), ``cpu``, ``cuda``, ``cuda:N``."""

from __future__ import annotations

import torch

from shsas_core.common.errors import ShsasError


def resolve_device(name: str = "auto") -> torch.device:
    """Return the torch device named by ``name``.

    Raises:
        ShsasError: for an unknown name or a CUDA device that is not present.
    """
    name = (name or "auto").strip().lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda" or name.startswith("cuda:"):
        if not torch.cuda.is_available():
            raise ShsasError(f"device: '{name}' requested but CUDA is not available (fix: use --device cpu or auto)")
        dev = torch.device(name)
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ShsasError(f"device: '{name}' does not exist ({torch.cuda.device_count()} CUDA devices)")
        return dev
    raise ShsasError(f"device: unknown device '{name}' (use auto, cpu, cuda or cuda:N)")


def describe_device(device: torch.device) -> str:
    """What ran a job, for its report and status: ``cpu``, or ``cuda:N (card name)``."""
    if device.type != "cuda":
        return device.type
    index = device.index if device.index is not None else torch.cuda.current_device()
    return f"cuda:{index} ({torch.cuda.get_device_name(index)})"
