"""Hydra multirun sweeps in MLflow: one parent run per sweep, a child run per job.

``MlflowSweepCallback`` (registered in ``conf/config.yaml`` under ``hydra.callbacks``) creates
the store and opens the parent run *before* any job starts, so parallel jobs never race on a
fresh SQLite file. Jobs find the parent through a file in the sweep folder, which works for
every launcher (in-process, joblib, Ray).

Every sweep ends with a summary (``summary.csv``, ``tradeoff.png`` with the Pareto front, both
also on the parent run) over the jobs that finished, and with the parent in a terminal state:

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

import numpy as np
import pandas as pd
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from pipeline.core.io import save_figure, write_csv, write_json
from pipeline.core.signals import install_for_process

log = logging.getLogger(__name__)
PARENT_FILE = "mlflow_parent_run_id"
JOB_RUN_FILE = "mlflow_run_id"
JOB_FAILED_FILE = "job_failed.json"
SUMMARY_METRICS = ["final_val_hole_mm", "final_val_hole_mm_p95", "final_val_collision_rate",
                   "final_val_any_violation_share", "final_train_seconds"]


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
                     "status": "FINISHED", **{f"metrics.final_{k}": v for k, v in final.items()
                                              if isinstance(v, (int, float))}})
    for path in sorted(folder.glob(f"*/{JOB_FAILED_FILE}")):
        failed = json.loads(path.read_text())
        rows.append({"run_id": path.parent.name, "tags.sweep.overrides": failed.get("overrides", ""),
                     "status": "FAILED"})
    return pd.DataFrame(rows)


def pareto_front(error: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Boolean mask of the points no other point beats on both error and collision rate."""
    pts = np.stack([error, rate], axis=1)
    better_eq = (pts[None, :, :] <= pts[:, None, :]).all(-1)
    strictly = (pts[None, :, :] < pts[:, None, :]).any(-1)
    dominated = (better_eq & strictly).any(axis=1)
    return ~dominated


def summary_table(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per child run: its overrides, final metrics and whether it is on the Pareto front
    (among the jobs that finished)."""
    cols = {"run_id": "run_id", "tags.sweep.overrides": "overrides", "status": "status"}
    df = runs.rename(columns=cols).reindex(columns=list(cols.values())).copy()
    for m in SUMMARY_METRICS:
        df[m.removeprefix("final_")] = runs[f"metrics.{m}"] if f"metrics.{m}" in runs else np.nan
    # Label each job by what it changes: drop the overrides every job of the sweep shares.
    tokens = [str(o).split() for o in df["overrides"].fillna("")]
    common = set.intersection(*map(set, tokens)) if len(tokens) > 1 else set()
    df["overrides"] = [" ".join(t for t in toks if t not in common) for toks in tokens]
    df = df.sort_values("overrides", kind="stable").reset_index(drop=True)
    ok = (df["status"] == "FINISHED") & df["val_hole_mm"].notna() & df["val_collision_rate"].notna()
    df["pareto"] = False
    if ok.any():
        df.loc[ok, "pareto"] = pareto_front(df.loc[ok, "val_hole_mm"].to_numpy(dtype=float),
                                            df.loc[ok, "val_collision_rate"].to_numpy(dtype=float))
    return df


def write_summary(folder: Path, runs: pd.DataFrame, client=None, parent: str | None = None) -> pd.DataFrame:
    """``summary.csv`` and ``tradeoff.png`` in the sweep folder, and on the parent run if any."""
    from pipeline.evaluation.plots import tradeoff_figure

    table = summary_table(runs)
    write_csv(table, folder / "summary.csv")
    fig = tradeoff_figure(table)
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
            mark_stale_runs(exp_id)
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
