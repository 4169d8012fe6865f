"""Where tensors live: CUDA when present (``device=auto``), else the CPU."""

from __future__ import annotations

import torch

from pipeline.core.errors import ConfigError


def resolve_device(name: str = "auto") -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device = {name!r}: CUDA is not available on this machine; use device=auto or cpu")
    try:
        return torch.device(name)
    except RuntimeError as exc:
        raise ConfigError(f"device = {name!r}: {exc}") from None


def configure_process(threads=None) -> None:
    """Process-wide settings, made once in a stage's ``main`` (never in ``run``, where they would
    leak from one call into the next): the number of torch CPU threads (``None``: torch's default)."""
    if threads is None:
        return
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < 1:
        raise ConfigError(f"threads = {threads!r}: expected a positive integer or null")
    torch.set_num_threads(threads)
