"""The exit codes of every stage (``python -m pipeline.<stage>``), one meaning each.

=====  =========================================================================================
code   meaning
=====  =========================================================================================
0      done
1      the result fails a check the user asked for (``strict=true``, ``schedule.strict``,
       ``execute.strict``); the result is written, the message says what failed and where
2      bad input or settings: a value out of range, a file that cannot be read, a mistyped setting
       name or another error of Hydra's composition (its message on stderr); nothing is written
3      the job could not finish with good input: no routes, a round that deadlocks, a training
       that diverged, the MLflow store locked past ``tracking.busy_timeout_s``, the independent
       checker's own failure, or a fault of the stage itself (its traceback on stderr); nothing
       is written
130    interrupted by SIGINT (Ctrl-C): 128 + 2
143    stopped by SIGTERM (``timeout``, Slurm, ``kill``): 128 + 15
=====  =========================================================================================

The independent round checker (``scripts/check_round.py``) imports nothing of ``pipeline``; its own
constants (``scripts/round_check/cli.py``) keep the same numbers for 0 to 3 (clean, violations, an
input it cannot judge, its own failure), and a test holds the two tables together.

:func:`exit_code` maps an exception to its code: the one table the stages (:func:`pipeline.core.stage.run_stage`,
:func:`pipeline.core.stage.stage_main`) read, so no stage writes a bare number.
"""

from __future__ import annotations

import enum
import signal


class ExitCode(enum.IntEnum):
    DONE = 0
    CHECK_FAILED = 1
    BAD_INPUT = 2
    JOB_FAILED = 3
    INTERRUPTED = 128 + signal.SIGINT
    TERMINATED = 128 + signal.SIGTERM


def for_signal(signum: int) -> int:
    """The exit status of a stage stopped by signal ``signum``: 128 + signum, as a shell reports a killed process."""
    return 128 + int(signum)


def hydra_errors() -> tuple[type[BaseException], ...]:
    """Hydra's own errors of composing the settings: a mistyped setting name, an unknown group option, an
    override it cannot parse, a missing config or search path."""
    from hydra.errors import CompactHydraException

    return (CompactHydraException,)  # ConfigCompositionException, MissingConfigException, OverrideParseException, ...


def exit_code(exc: BaseException) -> int:
    """The exit code for an exception that ends a stage (the table above)."""
    from pipeline.core.errors import ConfigError, InputError, JobFailed, StrictCheckFailed
    from pipeline.core.signals import Terminated

    if isinstance(exc, Terminated):
        return for_signal(exc.signum)
    if isinstance(exc, KeyboardInterrupt):
        return ExitCode.INTERRUPTED
    if isinstance(exc, StrictCheckFailed):
        return ExitCode.CHECK_FAILED
    if isinstance(exc, JobFailed):  # before ConfigError: nothing is both, but the job's failure is the finding
        return ExitCode.JOB_FAILED
    if isinstance(exc, (ConfigError, InputError, *hydra_errors())):
        return ExitCode.BAD_INPUT
    return ExitCode.JOB_FAILED
