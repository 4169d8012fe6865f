"""The MLflow dashboard on the project's store, opening on an experiment's runs table.

MLflow 3.17's UI does not read the ``mlflow.experimentKind`` tag: an experiment page shows its GenAI
overview unless the URL says ``workflowType=machine_learning`` (or the browser's localStorage key
``mlflow.workflowType`` does), as its bundle reads it (``e.get("workflowType")``). So the URL to give
is :func:`runs_url`'s, the runs route with that parameter.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Mapping

from pipeline.core.errors import ConfigError
from pipeline.tracking.runs import TrackingSettings, prepare_store


def runs_url(base: str, experiment_id: str) -> str:
    """The page of ``experiment_id``'s runs table on the UI at ``base`` (``http://127.0.0.1:5000``)."""
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs?workflowType=machine_learning"


def ui_command(settings: TrackingSettings, host: str, port: int) -> list[str]:
    """``mlflow ui`` on the store (one worker: the reference machine has 2 cores)."""
    return [sys.executable, "-m", "mlflow", "ui", "--backend-store-uri", settings.uri,
            "--default-artifact-root", settings.artifact_root.as_uri(), "--host", host, "--port", str(port),
            "--workers", "1"]


def ui_environment(environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The UI's environment: MLflow's server job execution off unless ``environ`` sets
    ``MLFLOW_SERVER_ENABLE_JOB_EXECUTION`` itself. It runs MLflow's GenAI jobs (judges, prompt
    optimisation, periodic trace tasks), none of which a training run uses, in eight more processes (a
    job runner and seven huey consumers): with it, the UI took 11 processes, 22-23 s of CPU and
    2.5-2.7 GB within 5 s of answering; without, 3, 8-10 s and 0.9 GB (docs/dashboard.md)."""
    return {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false", **environ}


def wait_until_up(base: str, timeout_s: float = 120.0, proc: subprocess.Popen | None = None) -> None:
    """Block until the UI at ``base`` answers its health check (or its process ends, or time runs out)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"mlflow ui exited with status {proc.returncode} before answering at {base}")
        try:
            urllib.request.urlopen(f"{base}/health", timeout=2).close()
            return
        except (urllib.error.URLError, OSError):
            time.sleep(0.5)
    raise TimeoutError(f"no MLflow UI answered at {base} within {timeout_s:.0f} s")


def port_free(host: str, port: int) -> bool:
    """Whether a server could listen on ``host:port`` now (a socket binds there, with SO_REUSEADDR as web
    servers set it: a port another process listens on is taken, one in TIME_WAIT is not)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except OSError:
        return True  # an unknown host: the UI names it itself
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError:
            return False
    return True


def listens_on(proc: subprocess.Popen, port: int) -> bool:
    """Whether ``proc`` or one of its children (mlflow ui runs its web server as a child) listens on ``port``."""
    import psutil

    try:
        root = psutil.Process(proc.pid)
        tree = [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return False
    for p in tree:
        try:
            conns = p.net_connections(kind="inet")
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
        if any(c.status == psutil.CONN_LISTEN and c.laddr and c.laddr.port == port for c in conns):
            return True
    return False


def _taken(settings: TrackingSettings) -> ConfigError:
    host, port = settings.ui_host, settings.ui_port
    return ConfigError(f"tracking.ui_port = {port}: {host}:{port} is in use by another process (another MLflow UI "
                       "there would show another store's runs); stop it, or choose a free port: "
                       f"tracking.ui_port={port + 1}")


def start(settings: TrackingSettings) -> tuple[subprocess.Popen | None, str]:
    """Start the UI on the store (none for an MLflow server URI: it is its own UI) and return it with
    the URL of the configured experiment's runs table; the experiment is created if missing. A port another
    process listens on is refused (:class:`ConfigError` naming it), before the UI starts and again once it
    answers (the answer must come from this UI, never from another store's)."""
    server = settings.uri.startswith(("http://", "https://"))
    if not server and not port_free(settings.ui_host, settings.ui_port):  # before any work
        raise _taken(settings)
    exp_id = prepare_store(settings)
    if server:
        return None, runs_url(settings.uri, exp_id)
    base = f"http://{settings.ui_host}:{settings.ui_port}"
    # its own process group: mlflow ui runs its web server as a child, and stop() ends both
    proc = subprocess.Popen(ui_command(settings, settings.ui_host, settings.ui_port), start_new_session=True,
                            env=ui_environment())
    try:
        try:
            wait_until_up(base, proc=proc)
        except RuntimeError:
            if not port_free(settings.ui_host, settings.ui_port):  # taken between the check and the UI's start
                raise _taken(settings) from None
            raise
        if not listens_on(proc, settings.ui_port):  # what answered is another server
            raise _taken(settings)
    except BaseException:
        stop(proc)
        raise
    return proc, runs_url(base, exp_id)


def stop(proc: subprocess.Popen, timeout_s: float = 3.0) -> None:
    """End the UI started by :func:`start` and its web server (SIGTERM to its group, SIGKILL if it
    lingers: its web server otherwise waits up to 30 s for open browser connections to close)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        except KeyboardInterrupt:  # a second Ctrl-C while stopping: at once
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
