"""The one check of a torch device asked for by name (``--device``, a config's ``device``)."""

from __future__ import annotations

import torch

from scenarios import InputError


def check_device(name: str | torch.device) -> torch.device:
    """The torch device ``name`` names, checked to exist on this machine.

    Args:
        name: ``cpu``, ``cuda``, ``cuda:N``, ``mps`` (or a ``torch.device``).

    Returns:
        The parsed ``torch.device``.

    Raises:
        InputError: torch does not know the name, or the machine has no such device; the
            message says what to use instead.
    """
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError):
        raise InputError(
            f"unknown device {name!r}; use cpu, cuda, cuda:N (N a CUDA device index) or mps"
        ) from None
    if device.type == "cpu":
        return device
    if device.type == "cuda":
        if not torch.cuda.is_available():
            build = " (this torch is a CPU-only build)" if torch.version.cuda is None else ""
            raise InputError(
                f"device {name!r}: CUDA is not available on this machine{build}; use cpu"
            )
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise InputError(
                f"device {name!r}: this machine has {count} CUDA device(s); use cuda:0 to "
                f"cuda:{count - 1}, or cpu"
            )
        return device
    if device.type == "mps":
        if not torch.backends.mps.is_available():
            raise InputError(f"device {name!r}: MPS is not available on this machine; use cpu")
        if device.index not in (None, 0):
            raise InputError(f"device {name!r}: there is one MPS device; use mps, or cpu")
        return device
    raise InputError(f"device {name!r}: only cpu, cuda and mps are supported; use cpu")
