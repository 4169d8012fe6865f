"""The one way a stage's ``main`` runs its ``run(cfg)``: threads from the runtime group, bad input as
one clear line.

Every stage module ends with::

    @hydra.main(version_base="1.3", config_path="../conf", config_name="config")
    def main(cfg: DictConfig) -> None:
        run_stage(cfg, run, threads="threads")

``threads`` names the ``runtime`` setting that sets torch's CPU threads for the stage
(``runtime.threads``, ``runtime.train_threads``, ``runtime.calibrate_threads``; conf/runtime/default.yaml
says why each has its value), or ``None`` for torch's default. A :class:`ConfigError` or
:class:`InputError` (a bad setting, a bad file: the message names the field or the file and row) ends
a single run with that message on stderr and exit status 2, not a traceback; under a multirun sweep it
is raised as it is, so Hydra's launcher records the job as failed and the sweep goes on.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable

from omegaconf import DictConfig

from pipeline.core.device import configure_process
from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import RuntimeSettings

log = logging.getLogger(__name__)
EXIT_BAD_INPUT = 2


def _single_run() -> bool:
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.get().mode == RunMode.RUN
    except (ImportError, ValueError):  # not under Hydra (a test calling main's body): a single run
        return True


def run_stage(cfg: DictConfig, run: Callable[[DictConfig], object], threads: str | None = "threads"):
    """Configure the process (``runtime.<threads>``), call ``run(cfg)`` and return its value."""
    runtime = RuntimeSettings.from_config(cfg)
    configure_process(None if threads is None else getattr(runtime, threads))
    try:
        return run(cfg)
    except (ConfigError, InputError) as exc:
        if not _single_run():
            raise
        log.error("%s", exc)
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(EXIT_BAD_INPUT) from None
