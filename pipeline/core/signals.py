"""SIGTERM and SIGINT as interrupts: how ``timeout``, Slurm and Ray (SIGTERM) and Ctrl-C or ``kill -INT``
(SIGINT) stop a job, turned into an exception in the main thread, so that runs are ended (KILLED) and
temporary files removed instead of left behind.

The handler raises at once, and also remembers the signal: a library that swallows the exception
(a retry loop with a bare ``except``, a native solver that runs on until its own limit) cannot make
the process carry on, because long loops call :func:`raise_if_terminated` and the stage's run checks
it again before it reports success. SIGINT is handled even where the process inherited it ignored
(a job started in the background with ``&``): a stage told to stop by ``kill -INT`` stops, as it does
on SIGTERM, instead of finishing its plan and replacing the previous outputs.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

_pending: int | None = None
HANDLED = (signal.SIGTERM, signal.SIGINT)


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGINT received; ``signum`` gives the exit status 128 + signum."""

    def __init__(self, signum: int):
        super().__init__(f"received {signal.Signals(signum).name}")
        self.signum = signum


def _handler(signum, _frame):
    global _pending
    _pending = signum
    raise Terminated(signum)


def pending() -> int | None:
    """The handled signal that arrived, if any: its exception may have come back wrapped by a native
    library's callback (numba re-raises it as ``SystemError``), so it cannot be told from the type."""
    return _pending


def raise_if_terminated() -> None:
    """Raise :class:`Terminated` if a handled signal arrived (and its first exception was swallowed)."""
    if _pending is not None:
        raise Terminated(_pending)


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """While inside, SIGTERM and SIGINT raise :class:`Terminated` in the main thread (elsewhere: no change)."""
    global _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, _handler) for s in HANDLED}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        _pending = None


def install_for_process() -> None:
    """SIGTERM raises :class:`Terminated` from now on in this process (a sweep's main process)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _handler)
