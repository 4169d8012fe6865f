"""Stage ``benchmark``: every solver and every trained network on the same holes, in one run.

    python -m pipeline.solver_benchmark                        # the five test groups (5 000 holes)
    python -m pipeline.solver_benchmark solver_benchmark.groups=[1] solver_benchmark.holes=100 \
        'solver_benchmark.methods=[cuikm,nm,hybrid]'

The slow population methods (a solver entry's ``max_holes``) solve the first holes only; the
``holes`` column says how many each method solved. The hybrid runs with the ``solver`` group.

Writes ``paths.data/benchmark/results.{csv,json,md}`` and ``figures/error_vs_time.png`` and logs
them to MLflow (run ``benchmark``). The harness: :mod:`pipeline.evaluation.solver_benchmark`.
"""

from __future__ import annotations

import platform

import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.assembly.build import build_safety
from pipeline.core.config import as_dict, project_path
from pipeline.core.settings import parse
from pipeline.core.stage import run_stage, stage_main
from pipeline.data.holes import joint_box
from pipeline.evaluation.plots import error_vs_time
from pipeline.evaluation.solver_benchmark import (
    COLUMNS,
    SolverBenchmarkSettings,
    benchmark_all,
    build_solvers,
    load_holes,
    write_results,
)
from pipeline.solvers.hybrid import HybridSettings
from pipeline.tracking.runs import TrackingSettings, stage_run

__all__ = ["COLUMNS", "run"]  # the table's columns, as tests read them from the stage


def run(cfg: DictConfig) -> pd.DataFrame:
    settings = parse(SolverBenchmarkSettings, OmegaConf.to_container(cfg.solver_benchmark, resolve=True),
                     "solver_benchmark")
    hybrid, tracking = parse(HybridSettings, cfg.solver, "solver"), TrackingSettings.from_config(cfg.tracking)
    data, out = project_path(cfg.paths.data), project_path(cfg.paths.data) / "benchmark"
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    pose = load_holes(data / "holes", settings.groups, settings.holes)
    box = cfg.holes.sup.get("box")
    solvers = build_solvers(settings.methods, settings.solvers, safety, data / "models",
                            joint_box(safety.boom, None if box is None else as_dict(box)), hybrid)
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "torch": torch.__version__, "threads": torch.get_num_threads(), "groups": settings.groups,
               "holes_per_group": settings.holes}
    with stage_run(tracking, "solver-benchmark", {"stage": "solver_benchmark"}) as mlrun:
        mlrun.log_params({"solver_benchmark": OmegaConf.to_container(cfg.solver_benchmark, resolve=True),
                          "solver": as_dict(cfg.solver), "machine": machine})
        df, references = benchmark_all(solvers, pose, safety, settings, mlrun)
        write_results(df, machine, out, references)
        mlrun.log_table(df, "tables/benchmark.json")
        mlrun.log_figure(error_vs_time(df), "figures/error_vs_time.png")
        mlrun.log_artifact(out / "results.csv")
    return df


@stage_main
def main(cfg: DictConfig) -> None:
    run_stage(cfg, run, threads="threads")


if __name__ == "__main__":
    main()
