"""The one way a stage's ``main`` runs its ``run(cfg)``: Hydra's composition, threads from the runtime group,
and an exit code with one meaning for each way a stage ends.

Every stage module ends with::

    @stage_main
    def main(cfg: DictConfig) -> None:
        run_stage(cfg, run, threads="threads")

:func:`stage_main` is ``@hydra.main`` on ``conf/config.yaml``; ``threads`` names the ``runtime`` setting
that sets torch's CPU threads for the stage (``runtime.threads``, ``runtime.train_threads``,
``runtime.calibrate_threads``; conf/runtime/default.yaml says why each has its value), or ``None`` for
torch's default.

Exit codes (the table is :mod:`pipeline.core.exit_codes`; docs/usage.md, "Exit codes"):

* 0: done.
* 1: the result, written, fails a check the user asked for (``strict=true``, ``schedule.strict``,
  ``execute.strict``: :class:`~pipeline.core.errors.StrictCheckFailed`); the message on stderr.
* 2: bad input or settings: a :class:`ConfigError` or :class:`InputError` (the message names the field,
  or the file and row), or an error of Hydra's own composition (a mistyped setting name, an unknown
  group option, an override it cannot parse: Hydra's message), before anything is written.
* 3: the job could not finish: a :class:`~pipeline.core.errors.JobFailed` (no routes, a deadlock, a
  diverged training, the MLflow store locked past ``tracking.busy_timeout_s``, the independent checker's
  own failure), or any other exception (a fault of the stage: Hydra prints its traceback). Outputs are
  published whole at the end, so nothing half-written is left.
* 130 / 143: SIGINT / SIGTERM (128 + the signal number; :func:`pipeline.tracking.runs.stage_run` ends the
  run KILLED and removes temporary files).

The errors of a single run end it with one line on stderr, not a traceback. Under a multirun sweep they are
raised as they are, so Hydra's launcher records the job as failed and the sweep goes on; the sweep then
exits with the code of the failure Hydra reports.
"""

from __future__ import annotations

import ast
import functools
import logging
import re
import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig

from pipeline.core.device import configure_process
from pipeline.core.errors import ConfigError, InputError, JobFailed, StrictCheckFailed
from pipeline.core.exit_codes import ExitCode, exit_code
from pipeline.core.settings import RuntimeSettings

log = logging.getLogger(__name__)


def _single_run() -> bool:
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.get().mode == RunMode.RUN
    except (ImportError, ValueError):  # not under Hydra (a test calling main's body): a single run
        return True


def run_stage(cfg: DictConfig, run: Callable[[DictConfig], object], threads: str | None = "threads"):
    """Configure the process (``runtime.<threads>``), call ``run(cfg)`` and return its value; a stage's own
    error ends a single run with its exit code (module docstring) and its message on stderr."""
    try:
        runtime = RuntimeSettings.from_config(cfg)
        configure_process(None if threads is None else getattr(runtime, threads))
        return run(cfg)
    except (ConfigError, InputError, JobFailed, StrictCheckFailed) as exc:
        if not _single_run():
            raise
        code = exit_code(exc)
        log.error("%s", exc)
        print(str(exc) if code == ExitCode.CHECK_FAILED else f"error: {exc}", file=sys.stderr)
        raise SystemExit(code) from None


def stage_main(task: Callable[[DictConfig], object]) -> Callable[..., object]:
    """``@hydra.main(version_base="1.3", config_path=<conf>, config_name="config")`` for a stage's ``main``, on
    the config folder :func:`pipeline.core.config.config_dir` gives (the checkout's ``conf/``, else the wheel's
    copy; an absolute path, so the stage composes the same whether run as ``python -m pipeline.<stage>`` or
    imported, as ``boom-ik <stage>`` does), with the stage exit codes where Hydra itself ends the process.
    Hydra reports an error of its own composition (a mistyped setting name: "Could not override
    'solve.strictt'") or an exception out of the task (a sweep's failed job, a fault) on stderr and exits 1;
    the code is taken here from that exception instead (:func:`pipeline.core.exit_codes.exit_code`: 2 for a
    composition error), Hydra's message kept."""
    import hydra

    from pipeline.core.config import config_dir

    hydra_main = hydra.main(version_base="1.3", config_path=str(config_dir()), config_name="config")(task)

    @functools.wraps(hydra_main)
    def main(cfg_passthrough: DictConfig | None = None):
        try:
            return hydra_main(cfg_passthrough)
        except SystemExit as exc:
            cause = exc.__context__
            if exc.code == 1 and isinstance(cause, Exception) and not exc.__suppress_context__:
                raise SystemExit(exit_code(cause)) from None  # Hydra's ``sys.exit(1)`` after reporting ``cause``
            raise
        except Exception as exc:  # HYDRA_FULL_ERROR=1 (or a debugger): Hydra raises instead of reporting
            traceback.print_exc()
            raise SystemExit(exit_code(exc)) from None

    return main


STAGE_MARK = "@stage_main\ndef main("  # how every stage module's main starts (tests/test_exit_codes.py holds it)
PACKAGE = Path(__file__).resolve().parents[1]  # pipeline/


def stage_modules(package: Path = PACKAGE) -> dict[str, str]:
    """``{stage: one line}`` for the modules of ``pipeline/`` whose ``main`` is a :func:`stage_main` (read from
    their source, nothing imported): the stages ``boom-ik`` runs, each with its docstring's first line."""
    stages = {}
    for path in sorted(package.glob("*.py")):
        text = path.read_text(encoding="utf-8")
        if STAGE_MARK in text:
            first = (ast.get_docstring(ast.parse(text)) or "").strip().splitlines()[:1]
            line = re.sub(r"^Stage(?: ``\w+``)?(?: \([^)]*\))?: ", "", first[0] if first else "")
            line = re.sub(r" \((?:docs/)[^)]*\)|, ``python -m [^`]*``", "", line).replace("``", "")
            stages[path.stem] = line[:1].upper() + line[1:]
    return stages
