"""Stage ``benchmark``: every solver and every trained network on the same holes, in one run.

    python -m pipeline.benchmark                        # test group 1, first 100 holes
    python -m pipeline.benchmark benchmark.holes=1000 'benchmark.methods=[cuikm,nm,cuikm_nm]'

Writes ``paths.data/benchmark/results.{csv,json,md}`` and ``figures/error_vs_time.png`` and logs
them to MLflow (run ``benchmark``). Times are wall clock on this machine with
``benchmark.threads`` torch threads; networks run on the CPU like the rest, for a fair race.
"""

from __future__ import annotations

import logging
import math
import platform
import statistics
import time
from dataclasses import dataclass, field

import hydra
import pandas as pd
import torch
from omegaconf import DictConfig, OmegaConf

from pipeline.core.build import build_safety
from pipeline.core.config import as_dict, project_path
from pipeline.core.device import configure_process
from pipeline.core.errors import ConfigError
from pipeline.core.io import save_figure, write_csv, write_json, write_text
from pipeline.core.settings import parse, rule
from pipeline.data.hole_sets import read_hole_poses
from pipeline.data.holes import joint_box
from pipeline.evaluation.markdown import markdown_table
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.evaluation.plots import error_vs_time
from pipeline.solvers import HoleTargets, Solver, build_solver
from pipeline.tracking.runs import TrackingSettings, stage_run

log = logging.getLogger(__name__)

COLUMNS = ["method", "holes", "hole_mm_mean", "hole_mm_p95", "hole_mm_max", "solved_1mm_share",
           "collision_rate_paper", "any_violation_share", "batch_ms_per_hole", "single_ms_per_hole",
           "iterations_mean", "setup_s"]


@dataclass(frozen=True)
class BenchmarkSettings:
    """The ``benchmark`` group's scalar settings (solvers are checked by ``build_solver``)."""

    group: int = field(metadata=rule(ge=1))
    holes: int = field(metadata=rule(ge=1))
    single: int = field(default=5, metadata=rule(ge=0))
    threads: int = field(default=2, metadata=rule(ge=1))
    methods: list[str] = field(default_factory=list)


def load_holes(holes_dir, group: int, n: int) -> torch.Tensor:
    _, pose = read_hole_poses(holes_dir, f"test_group_{group}.parquet")
    if not 1 <= n <= len(pose):
        raise ConfigError(f"benchmark.holes = {n}: test group {group} has {len(pose)} holes")
    return pose[:n].double()


def measure(solver: Solver, pose: torch.Tensor, depth: float, safety, single: int) -> tuple[dict, torch.Tensor]:
    """A batched solve of every hole (repeated up to 1 s for fast solvers, median time), then
    ``single`` holes one at a time (median latency)."""
    targets = HoleTargets(pose, depth)
    solver.solve(targets.subset([0]))  # warm-up: lazy setup (RBF fit, first kernels) is not timed
    result = solver.solve(targets)
    batch_s = [result.wall_s]
    while sum(batch_s) < 1.0 and len(batch_s) < 20:  # fast solvers: median of repeats, not one noisy sample
        batch_s.append(solver.solve(targets).wall_s)
    latencies = [solver.solve(targets.subset([i])).wall_s for i in range(min(single, len(targets)))]
    row = summarize(solution_table(pose, result.q, safety))
    return {
        "holes": len(targets),
        **{k: row[k] for k in ("hole_mm_mean", "hole_mm_p95", "hole_mm_max", "solved_1mm_share",
                               "collision_rate_paper", "any_violation_share")},
        "batch_ms_per_hole": 1000 * statistics.median(batch_s) / len(targets),
        "single_ms_per_hole": 1000 * statistics.median(latencies) if latencies else float("nan"),
        "iterations_mean": float(result.iterations.double().mean()),
    }, result.q


def markdown(df: pd.DataFrame) -> str:
    fmt = df.copy()
    for col in ["hole_mm_mean", "hole_mm_p95", "hole_mm_max"]:
        fmt[col] = fmt[col].map(lambda v: f"{v:.3g}" if v < 100 else f"{v:.0f}")
    for col in ["solved_1mm_share", "collision_rate_paper", "any_violation_share"]:
        fmt[col] = (100 * fmt[col]).map(lambda v: f"{v:.1f} %")
    for col in ["batch_ms_per_hole", "single_ms_per_hole"]:
        fmt[col] = fmt[col].map(lambda v: f"{v:.3g}")
    fmt["iterations_mean"] = fmt["iterations_mean"].map(lambda v: f"{v:.0f}")
    fmt["setup_s"] = fmt["setup_s"].map(lambda v: f"{v:.1f}")
    return markdown_table(fmt)


def build_solvers(methods: list[str], specs: dict, safety, models_dir,
                  start_box=None) -> dict[str, tuple[Solver, float]]:
    """Every solver built (networks loaded, RBF fitted) before the first solve: fail early."""
    unknown = [m for m in methods if m not in specs]
    if unknown:
        raise ConfigError(f"benchmark.methods: {unknown} have no entry under benchmark.solvers ({sorted(specs)})")
    solvers = {}
    for m in methods:
        start = time.perf_counter()
        solver = build_solver(m, specs[m], safety.boom, models_dir, specs, safety, start_box)
        if hasattr(solver, "fit"):
            solver.fit()
        solvers[m] = (solver, time.perf_counter() - start)
    return solvers


def run(cfg: DictConfig) -> pd.DataFrame:
    settings = parse(BenchmarkSettings, cfg.benchmark, "benchmark")
    tracking = TrackingSettings.from_config(cfg.tracking)
    data, out = project_path(cfg.paths.data), project_path(cfg.paths.data) / "benchmark"
    safety = build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    pose = load_holes(data / "holes", settings.group, settings.holes)
    box = cfg.holes.sup.get("box")
    solvers = build_solvers(settings.methods, OmegaConf.to_container(cfg.benchmark.solvers, resolve=True),
                            safety, data / "models", joint_box(safety.boom, None if box is None else as_dict(box)))
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "torch": torch.__version__, "threads": torch.get_num_threads(), "group": settings.group,
               "holes": settings.holes}
    with stage_run(tracking, "benchmark", {"stage": "benchmark"}) as mlrun:
        mlrun.log_params({"benchmark": OmegaConf.to_container(cfg.benchmark, resolve=True), "machine": machine})
        rows = []
        for m, (solver, setup_s) in solvers.items():
            row, _ = measure(solver, pose, safety.boom.preview_depth, safety, settings.single)
            rows.append({"method": m, **row, "setup_s": setup_s})
            mlrun.log_metrics(row, prefix=f"{m}.")
            log.info("%-10s mean %.4g mm, p95 %.4g mm, solved<=1mm %.1f %%, collisions %.1f %%, %.4g ms/hole batched",
                     m, row["hole_mm_mean"], row["hole_mm_p95"], 100 * row["solved_1mm_share"],
                     100 * row["collision_rate_paper"], row["batch_ms_per_hole"])
        df = pd.DataFrame(rows, columns=COLUMNS)
        write_results(df, machine, out)
        mlrun.log_table(df, "tables/benchmark.json")
        mlrun.log_figure(error_vs_time(df), "figures/error_vs_time.png")
        mlrun.log_artifact(out / "results.csv")
    return df


def write_results(df: pd.DataFrame, machine: dict, out) -> None:
    write_csv(df, out / "results.csv")
    # keyed by method so `dvc metrics show` / `dvc exp show` list one column per method and figure
    finite = lambda v: v if not isinstance(v, float) or math.isfinite(v) else None  # noqa: E731  NaN: not measured
    write_json({"machine": machine, **{r["method"]: {k: finite(v) for k, v in r.items() if k != "method"}
                                        for r in df.to_dict("records")}}, out / "results.json")
    write_text(f"Test group {machine['group']}, first {machine['holes']} holes; {machine['processor']}, "
               f"{machine['threads']} torch threads, torch {machine['torch']}.\n\n" + markdown(df), out / "results.md")
    save_figure(error_vs_time(df), out / "figures" / "error_vs_time.png")


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    configure_process(cfg.benchmark.threads)
    run(cfg)


if __name__ == "__main__":
    main()
