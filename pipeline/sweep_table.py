"""Stage ``sweep_table``: one accuracy-safety sweep of CUIKM, every job's every seed scored on the five test groups.

    python -m pipeline.sweep_table sweeps.table=mu          # what `dvc repro sweeps/dvc.yaml` runs per sweep

The jobs of sweep ``<s>`` (``sweeps.jobs`` whose ``sweep`` is ``<s>``) trained the method with one override each
into ``paths.data/sweeps/<s>/jobs/<job>/`` (sweeps/dvc.yaml); the reference point, the defaults alone, is the
study's own network in ``paths.data/models``. Each seed is scored as ``evaluate`` scores the study's networks, and
the swept settings are read from each network's own record, never from the job's name. Before anything is
written, every job's training settings are checked to differ from the reference's in the swept settings alone (a
job trained under other defaults would be a different study). Writes under ``paths.data/sweeps/<s>/``:

- ``predictions/<job>/seed<k>/group<g>.parquet``: each seed's joints for each test group;
- ``jobs.csv``: one row per job and seed: the swept settings, ``seed, mean_mm, p95_mm, collision_rate_pct,
  any_violation_pct, collisions_self, collisions_wall, collisions_ground, collisions_arch, val_hole_mm,
  train_seconds, predictions`` (the ``collisions_<kind>`` columns count the test holes whose answer breaks that
  reference distance; ``predictions`` is that seed's folder of group files, relative to the sweep's folder);
- ``summary.csv``: one row per job: the mean and sample std over its seeds, and whether the job's means are on
  the Pareto front of the sweep (no other job lower in both error and collision rate);
- ``tradeoff.png``: error against collision rate, seed std as bars, the front and Wu et al. 2024's networks
  (paper 000's numbers, ``pipeline/evaluation/paper_numbers.py``).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from pipeline.assembly.build import build_safety
from pipeline.core.config import as_dict, project_path
from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import publish, publish_lock, save_figure, staged_folder, write_csv, write_parquet
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.hole_sets import read_test_groups
from pipeline.evaluation.metrics import evaluate_network
from pipeline.evaluation.paper_numbers import PAPER000
from pipeline.evaluation.pareto import pareto_front
from pipeline.evaluation.plots import sweep_front_figure
from pipeline.evaluation.seeds import mean_std, seed_checkpoints
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.learning.network_source import load_network
from pipeline.tracking.runs import TrackingSettings, flatten, stage_run

log = logging.getLogger(__name__)
METHOD = "cuikm"   # the file stem of the networks a job trains (the `method` node is CUIKM)
# collisions_<kind>: the test holes (all five groups) whose answer breaks that reference distance: which distance
# the collision rate is made of, so a sweep shows which training distance moves it
KIND_COLUMNS = [f"collisions_{kind}" for kind in SAFETY_KINDS]
FIGURES = ["mean_mm", "p95_mm", "collision_rate_pct", "any_violation_pct", *KIND_COLUMNS, "val_hole_mm",
           "train_seconds"]
# a network's record differs from the reference's in these without being another study: its seed, how many seeds
# its job trained, and how the training ran (threads, progress), which train keeps out of its resume digest too
NOT_COMPARED = ("train.seed", "train.seeds", "runtime")


@dataclass(frozen=True)
class SweepSettings:
    """``sweeps``: the jobs (name -> sweep and override), the tables (sweep -> swept settings), which one to score."""

    jobs: dict
    tables: dict
    table: str | None
    reference: str

    @classmethod
    def from_config(cls, node) -> SweepSettings:
        node = as_dict(node) if node is not None else None
        if not isinstance(node, Mapping):
            raise ConfigError(f"sweeps: expected a config group, got {node!r}")
        unknown = set(node) - {"jobs", "tables", "table", "reference"}
        if unknown:
            raise ConfigError(f"sweeps: unknown key(s) {sorted(unknown)}; known: jobs, tables, table, reference")
        jobs, tables = node.get("jobs") or {}, node.get("tables") or {}
        for name, job in jobs.items():
            if not isinstance(job, Mapping) or set(job) != {"sweep", "set"}:
                raise ConfigError(f"sweeps.jobs.{name} = {job!r}: expected {{sweep: <a sweeps.tables key>, "
                                  f"set: <key>=<value>}}")
            if job["sweep"] not in tables:
                raise ConfigError(f"sweeps.jobs.{name}.sweep = {job['sweep']!r}: not a sweep of sweeps.tables "
                                  f"({sorted(tables)})")
            if not isinstance(job["set"], str) or "=" not in job["set"]:
                raise ConfigError(f"sweeps.jobs.{name}.set = {job['set']!r}: expected one override <key>=<value>")
        for name, keys in tables.items():
            if not isinstance(keys, list) or not keys or not all(isinstance(k, str) and k for k in keys):
                raise ConfigError(f"sweeps.tables.{name} = {keys!r}: expected a list of setting names "
                                  f"(e.g. [method.mu])")
        reference = node.get("reference")
        if not isinstance(reference, str) or not reference or reference in jobs:
            raise ConfigError(f"sweeps.reference = {reference!r}: expected a name that is not a job's")
        table = node.get("table")
        if table is not None and table not in tables:
            raise ConfigError(f"sweeps.table = {table!r}: not a sweep of sweeps.tables ({sorted(tables)})")
        return cls(jobs, tables, table, reference)

    def job_folders(self, data: Path) -> dict[str, Path]:
        """The networks' folder of each point of the chosen sweep, the reference first."""
        own = [name for name, job in self.jobs.items() if job["sweep"] == self.table]
        return {self.reference: data / "models",
                **{name: data / "sweeps" / self.table / "jobs" / name for name in own}}


def run(cfg: DictConfig) -> pd.DataFrame:
    settings, tracking = SweepSettings.from_config(cfg.get("sweeps")), TrackingSettings.from_config(cfg.tracking)
    if settings.table is None:
        raise ConfigError(f"sweeps.table is not set: name the sweep to score, one of {sorted(settings.tables)}")
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    data = project_path(cfg.paths.data)
    groups = read_test_groups(data / "holes")
    swept = settings.tables[settings.table]
    # every network loaded and checked before anything is written
    networks = {job: load_seeds(folder, job, safety.boom) for job, folder in settings.job_folders(data).items()}
    check_same_study(networks, settings.reference, swept)
    out = data / "sweeps" / settings.table
    with stage_run(tracking, f"sweep_table-{settings.table}", {"stage": "sweep_table", "sweep": settings.table}) \
            as mlrun:
        mlrun.log_params({"sweeps": {"table": settings.table, "swept": swept,
                                     "jobs": {j: settings.jobs[j]["set"] for j in networks if j in settings.jobs}}})
        rows, predictions = [], {}
        for job, seeds in networks.items():
            for seed, (model, meta) in seeds.items():
                result = evaluate_network(model, meta, safety, groups, 0)
                folder = Path("predictions") / job / f"seed{seed}"
                predictions.update({folder / f"group{k}.parquet": pred for k, pred in result.predictions.items()})
                rows.append(job_row(job, seed, meta, swept, result.metrics, folder))
        jobs = pd.DataFrame(rows)
        summary = job_summary(jobs, swept)
        fig = sweep_front_figure(summary, PAPER000, f"CUIKM, {settings.table} sweep: {len(summary)} settings, "
                                                    f"{jobs.groupby('job').size().min()}+ seeds each")
        write_set(out, predictions, jobs, summary, fig)
        mlrun.log_table(jobs, "tables/jobs.json")
        mlrun.log_table(summary, "tables/summary.json")
        mlrun.log_figure(fig, "figures/tradeoff.png")
        for _, row in summary.iterrows():
            mlrun.log_metrics({k: row[k] for k in ("mean_mm", "mean_mm_std", "collision_rate_pct",
                                                   "collision_rate_pct_std")}, prefix=f"{row['job']}.")
    for _, row in summary.iterrows():
        log.info("%s: %.2f +- %.2f mm, %.2f +- %.2f %% collisions over %d seeds%s", row["job"], row["mean_mm"],
                 row["mean_mm_std"], row["collision_rate_pct"], row["collision_rate_pct_std"], row["seeds"],
                 " (Pareto front)" if row["pareto"] else "")
    return summary


def write_set(out: Path, predictions: dict[Path, pd.DataFrame], jobs: pd.DataFrame, summary: pd.DataFrame,
              fig) -> None:
    """The sweep's files, written in a private folder and published together: an interrupted run leaves the
    earlier set whole, and the predictions folder is replaced whole (no file of a point since removed stays)."""
    with staged_folder(out, "sweep_table") as stage:
        for rel, pred in predictions.items():
            write_parquet(pred, stage / rel)
        write_csv(jobs, stage / "jobs.csv")
        write_csv(summary, stage / "summary.csv")
        save_figure(fig, stage / "tradeoff.png")
        publish({stage / name: out / name for name in ("jobs.csv", "summary.csv", "tradeoff.png")},
                publish_lock(out, "sweep_table"), folders={stage / "predictions": out / "predictions"})


def load_seeds(folder: Path, job: str, boom) -> dict[int, tuple]:
    """Every seed's network of one point, checked against the boom; a point without networks is an error."""
    paths = seed_checkpoints(folder, METHOD)
    if not paths:
        raise InputError(f"sweep point {job!r}: no networks {folder / f'{METHOD}_seeds'}/{METHOD}_seed<k>.pt "
                         f"(train it first: dvc repro sweeps/dvc.yaml)")
    return {seed: load_network(path, boom) for seed, path in paths.items()}


def setting(meta: dict, key: str, job: str, seed: int):
    """A training setting as the network's record holds it (``method.mu`` -> its ``config.method.mu``), as the
    text its MLflow run logs it with (``readable``: ``0.1``, ``10``)."""
    values = flatten(meta.get("config") or {})
    if key not in values:
        raise InputError(f"sweep point {job!r}, seed {seed}: its network's record has no setting {key!r}")
    return values[key]


def check_same_study(networks: dict[str, dict[int, tuple]], reference: str, swept: list[str]) -> None:
    """Every network was trained with the reference's settings but for the swept ones; InputError naming the
    first point and setting that differ otherwise."""
    def compared(meta):
        return {k: v for k, v in flatten(meta.get("config") or {}).items()
                if k not in swept and not any(k == n or k.startswith(n + ".") for n in NOT_COMPARED)}

    ref_seed, (_, ref_meta) = next(iter(networks[reference].items()))
    expected = compared(ref_meta)
    for job, seeds in networks.items():
        for seed, (_, meta) in seeds.items():
            got = compared(meta)
            differ = sorted(k for k in expected.keys() | got.keys()
                            if expected.get(k, "<none>") != got.get(k, "<none>"))
            if differ:
                k = differ[0]
                raise InputError(f"sweep point {job!r}, seed {seed}: trained with {k} = {got.get(k, '<none>')!r}, "
                                 f"the reference (seed {ref_seed}) with {expected.get(k, '<none>')!r}; a point may "
                                 f"differ in the swept settings {swept} alone ({len(differ)} setting(s) differ)")


def job_row(job: str, seed: int, meta: dict, swept: list[str], metrics: dict, folder: Path) -> dict:
    final = meta.get("final") or {}
    return {"job": job, **{key: setting(meta, key, job, seed) for key in swept}, "seed": seed,
            "mean_mm": metrics["hole_mm_mean"], "p95_mm": metrics["hole_mm_p95"],
            "collision_rate_pct": 100 * metrics["collision_rate_paper"],
            "any_violation_pct": 100 * metrics["any_violation_share"],
            **{col: metrics[col] for col in KIND_COLUMNS},
            "val_hole_mm": final.get("val_hole_mm"), "train_seconds": final.get("train_seconds"),
            "predictions": folder.as_posix()}


def job_summary(jobs: pd.DataFrame, swept: list[str]) -> pd.DataFrame:
    """One row per job: its swept settings, seeds, the mean and sample std of each figure; the Pareto front of the
    jobs' mean error and mean collision rate."""
    rows = []
    for job, seeds in jobs.groupby("job", sort=False):
        row = {"job": job, **{key: seeds[key].iloc[0] for key in swept}, "seeds": len(seeds)}
        for col in FIGURES:
            values = seeds[col].dropna()
            row[col], row[f"{col}_std"] = mean_std(values) if len(values) else (float("nan"), float("nan"))
        rows.append(row)
    summary = pd.DataFrame(rows)
    summary["pareto"] = pareto_front(summary["mean_mm"].to_numpy(float), summary["collision_rate_pct"].to_numpy(float))
    return summary


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads=None)


if __name__ == "__main__":
    main()
