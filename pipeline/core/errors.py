"""The errors that end a stage, one per exit code (:mod:`pipeline.core.exit_codes`).

* :class:`ConfigError`, :class:`InputError` (exit 2): bad settings or bad input. Both derive from
  ``ValueError`` so callers that already catch ``ValueError`` keep working; the message always names the
  field (or file/column/row) and the value.
* :class:`JobFailed` (exit 3): the settings and input were good, but the job could not finish (no routes,
  a deadlock, a diverged fit, a store locked by another process); the message names the problem and
  where it arose.
* :class:`StrictCheckFailed` (exit 1): the result, written, fails a check the user asked for (``strict``).
"""


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range."""


class InputError(ValueError):
    """Data handed to the pipeline (joints, poses, drill plans) is malformed."""


class JobFailed(RuntimeError):
    """The job could not finish, though its settings and input were accepted (exit 3)."""


class NoRoutes(JobFailed):
    """The planner found no feasible routing for the round."""


class Deadlock(JobFailed):
    """An execution of the round deadlocks: actions that wait on each other in a cycle."""


class Diverged(JobFailed):
    """A training or a fit diverged: a loss or parameters no longer finite."""


class StrictCheckFailed(Exception):
    """The result fails a check the user asked for with a ``strict`` setting (exit 1). Raised after the
    result is written; the message says what failed and where the result is."""
