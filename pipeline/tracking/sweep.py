"""Hydra multirun sweeps in MLflow: one parent run per sweep, a child run per job.

``MlflowSweepCallback`` (registered in ``conf/config.yaml`` under ``hydra.callbacks``) opens
the parent run and creates the store *before* any job starts, so parallel jobs never race
on a fresh SQLite file; when the sweep ends it logs the summary table and the
accuracy-safety plot with its Pareto front to the parent. Jobs find the parent through a
file in the sweep folder, which works for every launcher (in-process, joblib, Ray).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

log = logging.getLogger(__name__)
PARENT_FILE = "mlflow_parent_run_id"
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


def runs_from_job_files(folder: Path) -> pd.DataFrame:
    """The same columns as ``mlflow.search_runs`` gives, read from each job's ``*_final.json``
    (a sweep run without MLflow still gets its summary)."""
    import json

    rows = []
    for path in sorted(folder.glob("*/*_final.json")):
        final = json.loads(path.read_text())
        rows.append({"run_id": path.parent.name, "tags.sweep.overrides": final.get("overrides", ""),
                     "status": "FINISHED", **{f"metrics.final_{k}": v for k, v in final.items()
                                              if isinstance(v, (int, float))}})
    return pd.DataFrame(rows)


def pareto_front(error: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Boolean mask of the points no other point beats on both error and collision rate."""
    pts = np.stack([error, rate], axis=1)
    better_eq = (pts[None, :, :] <= pts[:, None, :]).all(-1)
    strictly = (pts[None, :, :] < pts[:, None, :]).any(-1)
    dominated = (better_eq & strictly).any(axis=1)
    return ~dominated


def summary_table(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per child run: its overrides, final metrics and whether it is on the Pareto front."""
    cols = {"run_id": "run_id", "tags.sweep.overrides": "overrides", "status": "status"}
    df = runs.rename(columns=cols)[list(cols.values())].copy()
    for m in SUMMARY_METRICS:
        df[m.removeprefix("final_")] = runs.get(f"metrics.{m}", np.nan)
    # Label each job by what it changes: drop the overrides every job of the sweep shares.
    tokens = [str(o).split() for o in df["overrides"].fillna("")]
    common = set.intersection(*map(set, tokens)) if len(tokens) > 1 else set()
    df["overrides"] = [" ".join(t for t in toks if t not in common) for toks in tokens]
    df = df.sort_values("overrides", kind="stable").reset_index(drop=True)
    ok = df["val_hole_mm"].notna() & df["val_collision_rate"].notna()
    df["pareto"] = False
    if ok.any():
        df.loc[ok, "pareto"] = pareto_front(df.loc[ok, "val_hole_mm"].to_numpy(),
                                            df.loc[ok, "val_collision_rate"].to_numpy())
    return df


def tradeoff_figure(df: pd.DataFrame):
    from pipeline.evaluation.plots import plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    ax.scatter(df["val_collision_rate"] * 100, df["val_hole_mm"], c="tab:blue", label="job")
    front = df[df["pareto"]].sort_values("val_collision_rate")
    ax.plot(front["val_collision_rate"] * 100, front["val_hole_mm"], "o-", color="tab:red", label="Pareto front")
    for _, row in df.iterrows():
        ax.annotate(row["overrides"], (row["val_collision_rate"] * 100, row["val_hole_mm"]), fontsize=7,
                    xytext=(3, 3), textcoords="offset points")
    ax.set_xlabel("collision rate on held-out holes (%)")
    ax.set_ylabel("mean hole-seeking error (mm)")
    ax.set_title("accuracy vs safety")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout(pad=1.5)
    return fig


class MlflowSweepCallback(Callback):
    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        if not config.tracking.enabled:
            return
        from mlflow.tracking import MlflowClient

        from pipeline.tracking import runs as tracking

        exp_id = tracking.setup(config.tracking.uri, config.tracking.experiment, config.tracking.artifact_root)
        folder = Path(config.hydra.sweep.dir)
        folder.mkdir(parents=True, exist_ok=True)
        sweep = " ".join(config.hydra.overrides.task)
        run = MlflowClient().create_run(exp_id, run_name=f"sweep {sweep}"[:250],
                                        tags={"stage": "sweep", "sweep.overrides": sweep})
        (folder / PARENT_FILE).write_text(run.info.run_id)
        log.info("MLflow parent run %s for sweep %s", run.info.run_id, sweep)

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        folder = Path(config.hydra.sweep.dir)
        parent = (folder / PARENT_FILE).read_text().strip() if (folder / PARENT_FILE).is_file() else None
        if config.tracking.enabled and parent:
            import mlflow

            from pipeline.tracking import runs as tracking

            tracking.setup(config.tracking.uri, config.tracking.experiment, config.tracking.artifact_root)
            exp_id = mlflow.get_run(parent).info.experiment_id
            runs = mlflow.search_runs([exp_id], filter_string=f"tags.mlflow.parentRunId = '{parent}'")
        else:
            runs = runs_from_job_files(folder)
        if runs.empty:
            log.warning("sweep %s: no finished job to summarise", folder)
            return
        table = summary_table(runs)
        table.to_csv(folder / "summary.csv", index=False)
        fig = tradeoff_figure(table)
        fig.savefig(folder / "tradeoff.png", dpi=120)
        if config.tracking.enabled and parent:
            with mlflow.start_run(run_id=parent):
                mlflow.log_table(table, "sweep/summary.json")
                mlflow.log_figure(fig, "sweep/tradeoff.png")
                mlflow.log_metrics({"jobs": len(table), "jobs_finished": int((table["status"] == "FINISHED").sum()),
                                    "pareto_points": int(table["pareto"].sum())})
        from pipeline.evaluation.plots import plt

        plt.close(fig)
        log.info("sweep summary (%d jobs): %s", len(table), folder / "summary.csv")
