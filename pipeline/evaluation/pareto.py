"""The sweep's trade-off: accuracy against safety of every job, and the Pareto front among them.

Input: one row per job in the columns ``mlflow.search_runs`` gives (``run_id``,
``tags.sweep.overrides``, ``status``, ``metrics.summary/*``); :mod:`pipeline.tracking.sweep` fetches
them and logs what this module computes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

SUMMARY_METRICS = ["summary/val_hole_mm", "summary/val_hole_mm_p95", "summary/val_collision_rate",
                   "summary/val_any_violation_share", "summary/train_seconds"]


def pareto_front(error: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Boolean mask of the points no other point beats on both error and collision rate."""
    pts = np.stack([error, rate], axis=1)
    better_eq = (pts[None, :, :] <= pts[:, None, :]).all(-1)
    strictly = (pts[None, :, :] < pts[:, None, :]).any(-1)
    dominated = (better_eq & strictly).any(axis=1)
    return ~dominated


def summary_table(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per child run (a job trains ``train.seeds`` networks, a run each): its overrides, seed, final
    metrics and whether it is on the Pareto front (among the runs that finished)."""
    cols = {"run_id": "run_id", "tags.sweep.overrides": "overrides", "tags.seed": "seed", "status": "status"}
    df = runs.rename(columns=cols).reindex(columns=list(cols.values())).copy()  # seed: a job trains train.seeds
    for m in SUMMARY_METRICS:
        df[m.removeprefix("summary/")] = runs[f"metrics.{m}"] if f"metrics.{m}" in runs else np.nan
    # Label each job by what it changes: drop the overrides every job of the sweep shares.
    tokens = [str(o).split() for o in df["overrides"].fillna("")]
    common = set.intersection(*map(set, tokens)) if len(tokens) > 1 else set()
    df["overrides"] = [" ".join(t for t in toks if t not in common) for toks in tokens]
    df = df.sort_values(["overrides", "seed"], kind="stable").reset_index(drop=True)
    ok = (df["status"] == "FINISHED") & df["val_hole_mm"].notna() & df["val_collision_rate"].notna()
    df["pareto"] = False
    if ok.any():
        df.loc[ok, "pareto"] = pareto_front(df.loc[ok, "val_hole_mm"].to_numpy(dtype=float),
                                            df.loc[ok, "val_collision_rate"].to_numpy(dtype=float))
    return df


def sweep_tradeoff(runs: pd.DataFrame):
    """The summary table (:func:`summary_table`) and its figure (error against collision rate, front marked)."""
    from pipeline.evaluation.plots import tradeoff_figure

    table = summary_table(runs)
    return table, tradeoff_figure(table)
