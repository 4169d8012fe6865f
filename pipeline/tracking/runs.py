"""MLflow for the stages: one store, one experiment, and one context manager per stage run.

Every stage logs through :func:`stage_run`, which is the one place that

* prepares the store: an absolute URI (so Hydra job folders and DVC temporary copies share one
  store), the SQLite schema created under a file lock (parallel first runs never race), a fast,
  named failure when the store or artifact folder cannot be written;
* tags the experiment ``mlflow.experimentKind = custom_model_development`` (MLflow 3.17's UI does not
  read it: the runs table opens from :func:`pipeline.tracking.dashboard.runs_url`, whose
  ``workflowType=machine_learning`` is what the UI reads);
* marks RUNNING runs of dead processes on this host as KILLED (what SIGKILL leaves behind);
* decides how a run ends: FINISHED, FAILED with the error as a tag, or KILLED on Ctrl-C / SIGTERM
  (the stage then exits with 128 + the signal number, as a killed process would).

With tracking off it yields a :class:`StageRun` whose logging calls do nothing, so stages never
branch on tracking and never import MLflow themselves.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import signal
import socket
import time
import urllib.error
import urllib.request
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from pipeline.core.config import main_root
from pipeline.core.errors import ConfigError, JobFailed
from pipeline.core.exit_codes import for_signal
from pipeline.core.io import file_md5, process_alive, require_writable
from pipeline.core.signals import Terminated, pending, raise_if_terminated, terminate_as_interrupt

log = logging.getLogger(__name__)

EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}
END_REASON = "run.end_reason"
MAX_BUSY_S = 86_400  # tracking.busy_timeout_s: conf/tracking/default.yaml


# ---------------------------------------------------------------------------------------- settings
def resolve_uri(uri: str | None) -> str:
    """The absolute tracking URI: ``uri``, else ``$MLFLOW_TRACKING_URI``, else the SQLite file
    ``mlflow.db`` in the main checkout. A relative SQLite path is taken from the main checkout (installed from
    the wheel, with no checkout: from the current working directory, :func:`pipeline.core.config.main_root`)."""
    uri = uri or os.environ.get("MLFLOW_TRACKING_URI") or "sqlite:///mlflow.db"
    if uri.startswith("sqlite:///"):
        path = Path(uri.removeprefix("sqlite:///"))
        if not path.is_absolute():
            path = main_root() / path
        return f"sqlite:///{path}"
    return uri


@dataclass(frozen=True)
class TrackingSettings:
    """The ``tracking`` config group, validated and made absolute."""

    enabled: bool
    uri: str
    experiment: str
    artifact_root: Path
    system_metrics: bool = False
    register_models: bool = True  # trained networks into the Model Registry as <experiment>-<method>
    ui_host: str = "127.0.0.1"  # python -m pipeline.dashboard: where the MLflow UI listens
    ui_port: int = 5000
    busy_timeout_s: float = 120.0  # how long to wait on a store another process holds locked

    @classmethod
    def from_config(cls, node: Mapping) -> TrackingSettings:
        enabled = node.get("enabled", True)
        if not isinstance(enabled, bool):
            raise ConfigError(f"tracking.enabled = {enabled!r}: expected true or false")
        experiment = node.get("experiment")
        if not isinstance(experiment, str) or not experiment.strip():
            raise ConfigError(f"tracking.experiment = {experiment!r}: expected a non-empty name")
        root = Path(node.get("artifact_root") or "mlartifacts")
        system_metrics = node.get("system_metrics", False)
        if not isinstance(system_metrics, bool):
            raise ConfigError(f"tracking.system_metrics = {system_metrics!r}: expected true or false")
        register = node.get("register_models", True)
        if not isinstance(register, bool):
            raise ConfigError(f"tracking.register_models = {register!r}: expected true or false")
        host, port = node.get("ui_host", "127.0.0.1"), node.get("ui_port", 5000)
        if not isinstance(host, str) or not host.strip():
            raise ConfigError(f"tracking.ui_host = {host!r}: expected a host name or address")
        if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
            raise ConfigError(f"tracking.ui_port = {port!r}: expected a port number (1-65535)")
        busy = node.get("busy_timeout_s", 120.0)
        if (isinstance(busy, bool) or not isinstance(busy, (int, float)) or not math.isfinite(busy) or busy < 0
                or busy > MAX_BUSY_S):
            raise ConfigError(f"tracking.busy_timeout_s = {busy!r}: expected a number of seconds in [0, {MAX_BUSY_S}] "
                              "(a day: a store locked longer is stuck, not busy)")
        settings = cls(enabled, resolve_uri(node.get("uri")), experiment,
                       root if root.is_absolute() else main_root() / root, system_metrics, register, host, port,
                       float(busy))
        if enabled:
            check_store(settings)  # with the other settings: before any data is read or run is opened
        return settings


# ---------------------------------------------------------------------------------------- store
def check_store(settings: TrackingSettings) -> None:
    """Fail in milliseconds, with the setting named, where MLflow would retry for minutes."""
    uri = settings.uri
    if uri.startswith("sqlite:///"):
        db = Path(uri.removeprefix("sqlite:///"))
        require_writable(db.parent, "tracking.uri (its folder)", ConfigError)
        if db.exists() and not os.access(db, os.R_OK | os.W_OK):
            raise ConfigError(f"tracking.uri = {uri}: the database file is not writable")
    elif uri.startswith(("http://", "https://")):
        try:
            urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=5).close()
        except (urllib.error.URLError, OSError) as exc:
            raise ConfigError(f"tracking.uri = {uri}: no MLflow server answers there ({exc}); start one, "
                              "or set tracking.uri=null for the local SQLite store") from None
    if not str(settings.artifact_root).startswith(("s3:", "gs:", "http:", "https:")):
        require_writable(settings.artifact_root, "tracking.artifact_root", ConfigError)


class StoreBusy(JobFailed):
    """The store stayed locked by another process for longer than ``tracking.busy_timeout_s`` (exit 3)."""


_BUSY = {"uri": "", "timeout_s": 120.0}  # the store of the current stage run (one per process)


def _is_locked(exc: BaseException) -> bool:
    """SQLite's "database is locked" (MLflow's SQLAlchemy store waits 20 s on the lock itself, then
    raises it as ``sqlalchemy.exc.OperationalError``, sometimes wrapped in an MlflowException)."""
    seen = 0
    while exc is not None and seen < 10:
        if "database is locked" in str(exc) or "database table is locked" in str(exc):
            return True
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return False


def waiting_on_busy_store(call, what: str, *args, **kwargs):
    """``call(*args, **kwargs)``, retried while the SQLite store is locked by another process (a paused
    or long write), up to ``tracking.busy_timeout_s`` in all; then :class:`StoreBusy` naming
    ``tracking.uri``, instead of a raw traceback."""
    start = time.monotonic()
    warned = False
    while True:
        try:
            return call(*args, **kwargs)
        except Exception as exc:
            if not _is_locked(exc):
                raise
            waited = time.monotonic() - start
            if waited >= _BUSY["timeout_s"]:
                raise StoreBusy(
                    f"tracking.uri = {_BUSY['uri']}: the MLflow store stayed locked by another process for "
                    f"{waited:.0f} s while {what} (tracking.busy_timeout_s = {_BUSY['timeout_s']:g}); wait for the "
                    "other run to finish or resume it, raise tracking.busy_timeout_s, or log to another store "
                    "(tracking.uri=...)") from None
            if not warned:
                log.warning("MLflow store %s is locked by another process; waiting up to %g s "
                            "(tracking.busy_timeout_s)", _BUSY["uri"], _BUSY["timeout_s"])
                warned = True
            time.sleep(min(1.0, max(0.0, _BUSY["timeout_s"] - waited)))


def wait_for_write_lock(settings: TrackingSettings) -> None:
    """Before MLflow opens a SQLite store: wait until no other process holds its write lock, up to
    ``tracking.busy_timeout_s`` (:func:`waiting_on_busy_store`), then :class:`StoreBusy`. MLflow's own
    wait on the lock is fixed at 20 s (``PRAGMA busy_timeout = 20000`` in ``mlflow/store/db/utils.py``),
    so without this a shorter setting would not be kept, and a longer one only in steps of 20 s.
    A store not made yet is left to MLflow."""
    if not settings.uri.startswith("sqlite:///"):
        return
    db = Path(settings.uri.removeprefix("sqlite:///"))
    if db.is_file():
        waiting_on_busy_store(_try_write_lock, "waiting for its write lock", db)


def _try_write_lock(db: Path) -> None:
    """Take the write lock and release it at once (``BEGIN IMMEDIATE``; readers are not blocked), or
    raise SQLite's "database is locked" after a short try: SQLite waits in C, where Ctrl-C and SIGTERM
    are not handled, so the waiting is done between tries."""
    import sqlite3

    con = sqlite3.connect(db, timeout=0.25, isolation_level=None)
    try:
        con.execute("BEGIN IMMEDIATE")
        con.execute("ROLLBACK")
    finally:
        con.close()


def prepare_store(settings: TrackingSettings) -> str:
    """Point MLflow at the store, create or migrate it once, make sure the experiment exists with
    its kind tag; returns the experiment id."""
    import mlflow
    from filelock import FileLock
    from mlflow.tracking import MlflowClient

    check_store(settings)
    mlflow.set_tracking_uri(settings.uri)
    lock = (FileLock(settings.uri.removeprefix("sqlite:///") + ".lock", timeout=300)
            if settings.uri.startswith("sqlite:///") else contextlib.nullcontext())
    with lock:  # schema creation, migration and experiment creation, one process at a time
        client = MlflowClient(settings.uri)
        exp = client.get_experiment_by_name(settings.experiment)
        if exp is None:
            exp_id = client.create_experiment(settings.experiment, artifact_location=settings.artifact_root.as_uri(),
                                              tags=EXPERIMENT_KIND)
        else:
            exp_id = exp.experiment_id
            if exp.tags.get("mlflow.experimentKind") is None:
                client.set_experiment_tag(exp_id, *next(iter(EXPERIMENT_KIND.items())))
    mlflow.set_experiment(experiment_id=exp_id)
    return exp_id


def process_tags() -> dict[str, str]:
    """Host, pid and the process's start time: enough to tell later whether the process still lives."""
    import psutil

    pid = os.getpid()
    return {"host": socket.gethostname(), "pid": str(pid), "pid_start": f"{psutil.Process(pid).create_time():.3f}"}


def _process_alive(pid: int, start: str | None) -> bool:
    try:
        return process_alive(pid, None if start is None else float(start))
    except ValueError:
        return False


def mark_stale_runs() -> list[str]:
    """End as KILLED the RUNNING runs, in every experiment of the store, that a process of this host
    started and that is gone (SIGKILL, power loss); returns their ids."""
    from mlflow.entities import ViewType
    from mlflow.tracking import MlflowClient

    client = MlflowClient()
    host = socket.gethostname()
    experiments = [e.experiment_id for e in client.search_experiments(view_type=ViewType.ALL)]
    runs = client.search_runs(experiments, f"attributes.status = 'RUNNING' and tags.host = '{host}'",
                              run_view_type=ViewType.ALL, max_results=1000) if experiments else []
    stale = []
    for run in runs:
        pid = run.data.tags.get("pid")
        if pid and pid.isdigit() and not _process_alive(int(pid), run.data.tags.get("pid_start")):
            client.set_tag(run.info.run_id, END_REASON, f"process {pid} on {host} ended without closing the run")
            client.set_terminated(run.info.run_id, "KILLED")
            stale.append(run.info.run_id)
    if stale:
        log.warning("marked %d stale RUNNING run(s) of dead processes as KILLED: %s", len(stale), stale)
    return stale


# ---------------------------------------------------------------------------------------- the run
def flatten(params: Mapping, prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": "1"}``; lists become JSON text."""
    out: dict[str, str] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{name}."))
        elif isinstance(value, (list, tuple)):
            out[name] = json.dumps([float(readable(v)) if isinstance(v, float) else v for v in value])
        else:
            out[name] = readable(value)
    return out


def select_params(cfg: Mapping, keys: list[str]) -> dict:
    """The settings a stage reads, by dotted key (``["method", "train", "holes.face_x"]``), as one nested
    dict: what a run logs as params, so a run holds its own settings and not every other stage's.
    A key missing from ``cfg`` is an error (a stage that lists it reads it)."""
    out: dict = {}
    for key in keys:
        node = cfg
        for part in key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                raise KeyError(f"select_params: no setting {key!r} in the config")
            node = node[part]
        *parents, last = key.split(".")
        target = out
        for part in parents:
            target = target.setdefault(part, {})
        target[last] = node
    return out


def readable(value, digits: int = 6) -> str:
    """A param as a user reads it: floats to ``digits`` significant digits, integral floats as ints."""
    if isinstance(value, float) and math.isfinite(value):
        return str(int(value)) if value.is_integer() and abs(value) < 1e15 else f"{value:.{digits}g}"
    return str(value)


def round_metric(value: float, digits: int = 4) -> float:
    """A summary value rounded to ``digits`` significant digits (the dashboard shows it as it is)."""
    return float(f"{value:.{digits}g}") if math.isfinite(value) else value


class StageRun:
    """Logging calls of one stage run; every call does nothing when tracking is off."""

    def __init__(self, run_id: str | None = None):
        self.run_id = run_id

    @property
    def active(self) -> bool:
        return self.run_id is not None

    def log_params(self, params: Mapping) -> None:
        if self.active:
            import mlflow

            logged = mlflow.tracking.MlflowClient().get_run(self.run_id).data.params  # a resumed run has some
            changed = sorted(k for k, v in flatten(params).items() if k in logged and logged[k] != v)
            if changed:  # MLflow refuses to change a param; only settings outside the resume digest can differ
                log.warning("run %s keeps its first values of %s", self.run_id, changed)
            items = [(k, v) for k, v in flatten(params).items() if k not in logged]
            for i in range(0, len(items), 100):  # MLflow takes at most 100 params a batch
                waiting_on_busy_store(mlflow.log_params, "logging params", dict(items[i : i + 100]))

    def log_metrics(self, metrics: Mapping, step: int | None = None, prefix: str = "") -> None:
        """Finite numbers only (MLflow stores NaN, but a dashboard curve through NaN says nothing)."""
        if self.active:
            import mlflow

            clean = {f"{prefix}{k}": float(v) for k, v in metrics.items()
                     if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)}
            if clean:
                waiting_on_busy_store(mlflow.log_metrics, "logging metrics", clean, step=step)

    def set_tags(self, tags: Mapping[str, str]) -> None:
        if self.active:
            import mlflow

            waiting_on_busy_store(mlflow.set_tags, "setting tags", dict(tags))

    def log_table(self, df, path: str) -> None:
        """A DataFrame as an MLflow table artifact (object columns as text, which the viewer needs)."""
        if self.active:
            import mlflow

            waiting_on_busy_store(mlflow.log_table, f"logging {path}",
                                  df.astype({c: str for c in df.columns if df[c].dtype == object}), path)

    def log_figure(self, fig, path: str) -> None:
        if self.active:
            import mlflow

            waiting_on_busy_store(mlflow.log_figure, f"logging {path}", fig, path)

    def log_text(self, text: str, path: str) -> None:
        if self.active:
            import mlflow

            waiting_on_busy_store(mlflow.log_text, f"logging {path}", text, path)

    def log_artifact(self, path: str | Path, folder: str | None = None) -> None:
        if self.active:
            import mlflow

            if Path(path).is_dir():
                waiting_on_busy_store(mlflow.log_artifacts, f"logging {path}", str(path), folder)
            else:
                waiting_on_busy_store(mlflow.log_artifact, f"logging {path}", str(path), artifact_path=folder)

    def log_network(self, model, input_example, checkpoint: str | Path, name: str = "model", step: int = 0,
                    registered_name: str | None = None, alias: str = "newest"):
        """The trained network as an MLflow model named ``name`` at training step ``step`` (MLflow links
        that step's metrics to it), optionally registered as ``registered_name`` with ``alias`` moved to
        the new version (``models:/<registered_name>@newest``); returns MLflow's ``ModelInfo`` (or None).

        Never pickled: the model is a ``torch.export`` program (MLflow's ``pt2``, which loads without
        running code) and carries the project's weights-only checkpoint as an extra file, which is
        what :func:`pipeline.learning.network_source.load_network` reads back as the :class:`IKNet` it is."""
        if self.active:
            import mlflow.pytorch

            info = mlflow.pytorch.log_model(model, name=name, input_example=input_example, pip_requirements=["torch"],
                                            registered_model_name=registered_name, serialization_format="pt2",
                                            extra_files=[str(checkpoint)], step=int(step))
            if registered_name and info.registered_model_version is not None:
                from mlflow.tracking import MlflowClient

                MlflowClient().set_registered_model_alias(registered_name, alias, str(info.registered_model_version))
            return info
        return None

    def log_summary(self, metrics: Mapping, step: int, model_id: str | None = None, dataset=None,
                    prefix: str = "summary/", digits: int = 4) -> None:
        """Single values of the run (``summary/val_hole_mm``), rounded for reading, at ``step``, linked to the
        logged model ``model_id`` and evaluated on ``dataset`` (the model page then lists that dataset).
        Logged after the curves; the ``summary/`` prefix puts them in a chart section of their own."""
        if self.active:
            import mlflow
            from mlflow.entities import Metric

            ts = int(time.time() * 1000)
            ds_name, ds_digest = (dataset.name, dataset.digest) if dataset is not None else (None, None)
            batch = [Metric(f"{prefix}{k}", round_metric(float(v), digits), ts, int(step), model_id=model_id,
                            dataset_name=ds_name, dataset_digest=ds_digest, run_id=self.run_id)
                     for k, v in metrics.items()
                     if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
            if batch:
                mlflow.tracking.MlflowClient().log_batch(self.run_id, metrics=batch)

    def log_frame_dataset(self, df, name: str, context: str):
        """A table the run drew itself (no file), as an MLflow dataset whose digest is its values' MD5."""
        if self.active:
            import hashlib

            import mlflow
            import mlflow.data

            digest = hashlib.md5(df.to_numpy().tobytes()).hexdigest()
            ds = mlflow.data.from_pandas(df, name=name, digest=digest)
            mlflow.log_input(ds, context=context)
            return ds
        return None

    def log_dataset(self, df, path: str | Path, context: str, digest: str | None = None):
        """A table the run read, as an MLflow dataset input whose digest is the file's MD5, the hash
        DVC records for it: the runs' Dataset column then names the same data version as dvc.lock.
        Returns the MLflow dataset (to link metrics to it), or None with tracking off."""
        if self.active:
            import mlflow
            import mlflow.data

            path = Path(path)
            with warnings.catch_warnings():  # MLflow registers two equivalent sources for local files
                warnings.filterwarnings("ignore", message="The specified dataset source can be interpreted")
                ds = mlflow.data.from_pandas(df, source=str(path), name=path.name, digest=digest or file_md5(path))
            waiting_on_busy_store(mlflow.log_input, f"logging the dataset {path.name}", ds, context=context)
            return ds
        return None


@contextlib.contextmanager
def stage_run(settings: TrackingSettings, run_name: str, tags: Mapping[str, str] | None = None,
              system_metrics: bool = False, resume_run_id: str | None = None) -> Iterator[StageRun]:
    """One MLflow run around a stage's work; how it ends is decided here and nowhere else.

    SIGTERM is turned into an interrupt for the duration, with tracking on or off, so that
    temporary files of atomic writes are removed and the process exits with 128 + 15.
    ``resume_run_id``: the run of an interrupted training that this one continues (see :func:`_start`)."""
    with terminate_as_interrupt():
        if not settings.enabled:
            try:
                yield StageRun()
                raise_if_terminated()
            except Terminated as exc:
                raise SystemExit(for_signal(exc.signum)) from exc
            except Exception as exc:
                if pending() is None:
                    raise
                raise SystemExit(for_signal(pending())) from exc  # the signal's exception, wrapped
            return
        _BUSY.update(uri=settings.uri, timeout_s=settings.busy_timeout_s)
        try:  # a signal while waiting on the store: no run exists yet, so only the exit status to set
            wait_for_write_lock(settings)
            exp_id = waiting_on_busy_store(prepare_store, "opening the experiment", settings)
            waiting_on_busy_store(mark_stale_runs, "marking stale runs")
            run = waiting_on_busy_store(_start, "starting the run", exp_id, run_name,
                                        {**process_tags(), **dict(tags or {})},
                                        bool(system_metrics and settings.system_metrics), resume_run_id)
        except Terminated as exc:
            raise SystemExit(for_signal(exc.signum)) from exc
        run_id = run.info.run_id
        try:
            yield StageRun(run_id)
            raise_if_terminated()  # a SIGTERM whose exception some library swallowed
        except KeyboardInterrupt as exc:
            reason = str(exc) or "interrupted (SIGINT / Ctrl-C)"
            _end(run_id, "KILLED", reason)
            if isinstance(exc, Terminated):
                raise SystemExit(for_signal(exc.signum)) from exc
            raise
        except BaseException as exc:
            signum = pending()
            if signum is not None:  # the signal's exception, wrapped on its way out (numba: SystemError)
                _end(run_id, "KILLED", f"received {signal.Signals(signum).name} ({type(exc).__name__} on the way out)")
                raise SystemExit(for_signal(signum)) from exc
            _end(run_id, "FAILED", f"{type(exc).__name__}: {exc}"[:5000])
            raise
        else:
            _end(run_id, "FINISHED", None)


def _start(exp_id: str, run_name: str, tags: dict[str, str], system_metrics: bool, resume_run_id: str | None):
    """A new run, or, for a resumed training, its interrupted run continued: the same run when this
    store holds it in this experiment and it did not finish (its curves then go on where they
    stopped), else a new run tagged ``resumed_from`` with the old id."""
    import mlflow
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    if resume_run_id:
        try:
            old = MlflowClient().get_run(resume_run_id)
        except MlflowException:
            old = None
        if (old is not None and old.info.experiment_id == exp_id and old.info.status != "FINISHED"
                and old.info.lifecycle_stage == "active"):
            if END_REASON in old.data.tags:  # it ends again, with its own reason
                MlflowClient().delete_tag(resume_run_id, END_REASON)
            return mlflow.start_run(run_id=resume_run_id, tags={**tags, "resumed": "true"},
                                    log_system_metrics=system_metrics)
        tags = {**tags, "resumed_from": resume_run_id}
    return mlflow.start_run(experiment_id=exp_id, run_name=run_name, tags=tags, log_system_metrics=system_metrics)


def _end(run_id: str, status: str, reason: str | None) -> None:
    import mlflow

    if reason:
        with contextlib.suppress(Exception):  # the store itself may be what failed
            waiting_on_busy_store(mlflow.set_tag, "recording why the run ended", END_REASON, reason)
    waiting_on_busy_store(mlflow.end_run, f"ending the run {status}", status)
    if status != "FINISHED":
        log.error("MLflow run %s ended %s: %s", run_id, status, reason)


def log_training_progress(run: StageRun, step: int, steps: int, record: Mapping[str, float], elapsed: float,
                          method: str, echo: bool) -> None:
    """Held-out metrics at each evaluation, while training runs (the dashboard draws live curves),
    and, without a progress bar (under DVC), one line a user can tell from a hang."""
    run.log_metrics({k: v for k, v in record.items() if k != "step"}, step=step)
    if echo:
        done = (step + 1) / steps
        left = elapsed / done - elapsed if done > 0 else math.nan
        log.info("train %s: step %d/%d (%.0f %%), loss %.4g, held-out %.2f mm, %.0f s elapsed, ~%.0f s left",
                 method, step + 1, steps, 100 * done, record.get("loss", math.nan), record.get("val_hole_mm", math.nan),
                 elapsed, left)


def register_network(model_uri: str, registered_name: str, alias: str = "newest") -> None:
    """Register a network logged by :meth:`StageRun.log_network` (``models:/<model id>``) as a new version of
    ``registered_name`` and move ``alias`` to it: done once a training's seeds are compared, for the one kept."""
    import mlflow
    from mlflow.tracking import MlflowClient

    version = mlflow.register_model(model_uri, registered_name)
    MlflowClient().set_registered_model_alias(registered_name, alias, str(version.version))
