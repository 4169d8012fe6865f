"""Hydra multirun sweeps in MLflow: one parent run per sweep, a child run per job.

``MlflowSweepCallback`` (registered in ``conf/config.yaml`` under ``hydra.callbacks``) creates
the store and opens the parent run *before* any job starts, so parallel jobs never race on a
fresh SQLite file. Jobs find the parent through a file in the sweep folder, which works for
every launcher (in-process, joblib, Ray).

Every sweep ends with a summary (``summary.csv``, ``tradeoff.png`` with the Pareto front, both
also on the parent run; computed by :mod:`pipeline.evaluation.pareto`) over the jobs that
finished, and with the parent in a terminal state:

* all jobs finished: FINISHED;
* a job failed: its child run is FAILED (created here if the job failed before it could open
  one), and the parent ends FAILED. Hydra skips ``on_multirun_end`` when a job fails, so the
  summary is then written by an exit handler of the sweep's main process;
* the sweep is interrupted (Ctrl-C, SIGTERM): the same exit handler ends the parent KILLED.
"""

from __future__ import annotations

import atexit
import json
import logging
from pathlib import Path

import pandas as pd
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from pipeline.core.io import save_figure, write_csv, write_json
from pipeline.core.signals import install_for_process
from pipeline.evaluation.pareto import sweep_tradeoff

log = logging.getLogger(__name__)
PARENT_FILE = "mlflow_parent_run_id"
JOB_RUN_FILE = "mlflow_run_id"
JOB_FAILED_FILE = "job_failed.json"


def _sweep_dir() -> Path | None:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized():
        return None
    hc = HydraConfig.get()
    return Path(hc.sweep.dir) if hc.mode == RunMode.MULTIRUN else None


def job_output_dir() -> Path | None:
    """The Hydra job folder of a multirun job (each job saves its own model there), else None."""
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir) if _sweep_dir() is not None else None


def job_overrides() -> str:
    """The command-line overrides of the current Hydra job ("" outside Hydra)."""
    from hydra.core.hydra_config import HydraConfig

    return " ".join(HydraConfig.get().overrides.task) if HydraConfig.initialized() else ""


def child_tags() -> dict[str, str]:
    """Tags that make the current job a child of its sweep's parent run (empty outside sweeps)."""
    from hydra.core.hydra_config import HydraConfig

    folder = _sweep_dir()
    if folder is None or not (folder / PARENT_FILE).is_file():
        return {}
    return {
        "mlflow.parentRunId": (folder / PARENT_FILE).read_text().strip(),
        "sweep.overrides": job_overrides(),
        "sweep.job": str(HydraConfig.get().job.num),
    }


def record_job_run(run_id: str | None) -> None:
    """Leave the job's run id in its folder, so a failed job is known to have its own FAILED run."""
    folder = job_output_dir()
    if folder is not None and run_id:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / JOB_RUN_FILE).write_text(run_id)


# ---------------------------------------------------------------------------------------- summary
def runs_from_job_files(folder: Path) -> pd.DataFrame:
    """The same columns as ``mlflow.search_runs`` gives, read from each job's ``*_final.json``
    (finished) and ``job_failed.json`` (failed): a sweep without MLflow still gets its summary."""
    rows = []
    for path in sorted(folder.glob("*/*_final.json")):
        final = json.loads(path.read_text())
        rows.append({"run_id": path.parent.name, "tags.sweep.overrides": final.get("overrides", ""),
                     "tags.seed": final.get("seed"), "status": "FINISHED",
                     **{f"metrics.summary/{k}": v for k, v in final.items() if isinstance(v, (int, float))}})
    for path in sorted(folder.glob(f"*/{JOB_FAILED_FILE}")):
        failed = json.loads(path.read_text())
        rows.append({"run_id": path.parent.name, "tags.sweep.overrides": failed.get("overrides", ""),
                     "status": "FAILED"})
    return pd.DataFrame(rows)


def write_summary(folder: Path, runs: pd.DataFrame, client=None, parent: str | None = None) -> pd.DataFrame:
    """``summary.csv`` and ``tradeoff.png`` in the sweep folder, and on the parent run if any."""
    table, fig = sweep_tradeoff(runs)
    write_csv(table, folder / "summary.csv")
    save_figure(fig, folder / "tradeoff.png")
    if client is not None and parent:
        client.log_table(parent, table.astype({"overrides": str, "status": str}), "sweep/summary.json")
        client.log_figure(parent, fig, "sweep/tradeoff.png")
        for key, value in {"jobs": len(table), "jobs_finished": int((table["status"] == "FINISHED").sum()),
                           "jobs_failed": int((table["status"] == "FAILED").sum()),
                           "pareto_points": int(table["pareto"].sum())}.items():
            client.log_metric(parent, key, value)
    log.info("sweep summary (%d jobs): %s", len(table), folder / "summary.csv")
    return table


# ---------------------------------------------------------------------------------------- callback
class MlflowSweepCallback(Callback):
    def __init__(self) -> None:
        self._open: tuple[Path, object | None, str | None] | None = None  # folder, client, parent

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        folder = Path(config.hydra.sweep.dir)
        folder.mkdir(parents=True, exist_ok=True)
        client, parent = None, None
        if config.tracking.enabled:
            from mlflow.tracking import MlflowClient

            from pipeline.tracking.runs import TrackingSettings, mark_stale_runs, prepare_store, process_tags

            settings = TrackingSettings.from_config(config.tracking)
            exp_id = prepare_store(settings)
            mark_stale_runs()
            client = MlflowClient(settings.uri)
            sweep = " ".join(config.hydra.overrides.task)
            run = client.create_run(exp_id, run_name=f"sweep {sweep}"[:250],
                                    tags={"stage": "sweep", "sweep.overrides": sweep, **process_tags()})
            parent = run.info.run_id
            (folder / PARENT_FILE).write_text(parent)
            log.info("MLflow parent run %s for sweep %s", parent, sweep)
        self._open = (folder, client, parent)
        atexit.register(self._finish_at_exit)  # Hydra skips on_multirun_end when a job fails
        install_for_process()  # SIGTERM ends the sweep through the exit handler too

    def on_job_end(self, config: DictConfig, job_return, **kwargs) -> None:
        """In the job's own process: a failed job leaves a trace the summary can count."""
        from hydra.core.utils import JobStatus

        folder = job_output_dir()
        if folder is None or job_return.status != JobStatus.FAILED:
            return
        error = f"{type(job_return._return_value).__name__}: {job_return._return_value}"[:5000]
        write_json({"overrides": job_overrides(), "error": error}, folder / JOB_FAILED_FILE)
        tags = child_tags()
        if config.tracking.enabled and tags and not (folder / JOB_RUN_FILE).is_file():
            from mlflow.tracking import MlflowClient

            from pipeline.tracking.runs import END_REASON, TrackingSettings

            settings = TrackingSettings.from_config(config.tracking)
            client = MlflowClient(settings.uri)
            exp_id = client.get_run(tags["mlflow.parentRunId"]).info.experiment_id
            run = client.create_run(exp_id, run_name=f"failed job {tags['sweep.job']}",
                                    tags={**tags, "stage": "train", END_REASON: error})
            client.set_terminated(run.info.run_id, "FAILED")

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        self._finish(interrupted=False)

    def _finish_at_exit(self) -> None:
        self._finish(interrupted=True)

    def _finish(self, interrupted: bool) -> None:
        if self._open is None:
            return
        folder, client, parent = self._open
        self._open = None
        atexit.unregister(self._finish_at_exit)
        if client is not None:
            import mlflow

            exp_id = client.get_run(parent).info.experiment_id
            runs = mlflow.search_runs([exp_id], filter_string=f"tags.mlflow.parentRunId = '{parent}'")
        else:
            runs = runs_from_job_files(folder)
        failed = int((runs["status"] != "FINISHED").sum()) if not runs.empty else 0
        if not runs.empty:
            write_summary(folder, runs, client, parent)
        else:
            log.warning("sweep %s: no job to summarise", folder)
        if client is not None:
            from pipeline.tracking.runs import END_REASON

            status = "FAILED" if failed else "KILLED" if interrupted else "FINISHED"
            if status != "FINISHED":
                client.set_tag(parent, END_REASON, f"{failed} job(s) failed" if failed else "sweep interrupted")
            client.set_terminated(parent, status)
