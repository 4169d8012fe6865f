"""The solver benchmark's harness: every solver built before the first solve, each timed batched and one
hole at a time on the same holes, the results table and its Markdown (stage ``benchmark``, docs/benchmarks.md).

Times are wall clock with the process's torch threads (``runtime.threads`` in the stage); networks run on
the CPU like the rest, for a fair race."""

from __future__ import annotations

import logging
import math
import statistics
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import ConfigError
from pipeline.core.io import save_figure, write_csv, write_json, write_text
from pipeline.core.settings import rule
from pipeline.data.hole_sets import MAX_SET, MAX_TEST_GROUPS, read_hole_poses
from pipeline.evaluation.markdown import markdown_table
from pipeline.evaluation.metrics import solution_table, summarize
from pipeline.evaluation.paper_experiments import PapersSettings
from pipeline.evaluation.peer_timing import single_latencies, threads
from pipeline.evaluation.plots import error_vs_time
from pipeline.evaluation.status_reference import status_agreement
from pipeline.solvers import HARNESS_BOUNDS, HoleTargets, Solver, SolveResult, build_solver, check_entry
from pipeline.solvers.hybrid import HybridSettings
from pipeline.solvers.peers import PeersUnavailable

log = logging.getLogger(__name__)

COLUMNS = ["method", "holes", "hole_mm_mean", "hole_mm_p95", "hole_mm_max", "solved_1mm_share",
           "collision_rate_paper", "any_violation_share", "ok_share", "batch_ms_per_hole", "holes_per_s",
           "single_ms_per_hole", "single_ms_p95", "single_ms_p99", "single_ms_max", "single_holes",
           "iterations_mean", "setup_s"]
OK_MM = 0.01  # "ok" for every method alike: hole-seeking error <= 0.01 mm and no safety violation


@dataclass(frozen=True)
class SolverBenchmarkSettings:
    """The ``benchmark`` group (each solver entry is checked by ``build_solver``, ``papers`` by paper_baselines)."""

    groups: list[int] = field(metadata=rule(ge=1, le=MAX_TEST_GROUPS, min_items=1, max_items=MAX_TEST_GROUPS))
    holes: int = field(metadata=rule(ge=1, le=MAX_SET))  # per group
    methods: list[str]
    solvers: dict  # method -> its entry (kind and that solver's parameters; its sizes checked here)
    papers: PapersSettings  # paper_baselines' experiments
    single: int = field(default=20, metadata=rule(ge=0, le=HARNESS_BOUNDS["single"][1]))  # holes solved alone, one
    # thread (a solver entry's own ``single`` overrides it: the rows whose tail is a target take 1 000)
    reference_ok_sample: int = field(default=200, metadata=rule(ge=0, le=100_000))  # hybrid statuses vs a slow search

    def __post_init__(self):
        if not isinstance(self.solvers, Mapping):
            raise ConfigError(f"solver_benchmark.solvers = {self.solvers!r}: expected a mapping method -> entry")
        for name, spec in self.solvers.items():
            check_entry(str(name), spec)


def load_holes(holes_dir, groups: list[int], n: int) -> torch.Tensor:
    """The first ``n`` holes of each test group, in group order."""
    poses = []
    for group in groups:
        _, pose = read_hole_poses(holes_dir, f"test_group_{group}.parquet")
        if not 1 <= n <= len(pose):
            raise ConfigError(f"solver_benchmark.holes = {n}: test group {group} has {len(pose)} holes")
        poses.append(pose[:n].double())
    return torch.cat(poses)


def measure(solver: Solver, pose: torch.Tensor, depth: float, safety, single: int) -> tuple[dict, SolveResult]:
    """A batched solve of every hole (repeated up to 1 s for fast solvers, median time), then the first
    ``single`` holes one at a time on one thread (torch and numba), as a controller asks for one hole:
    the median and the tail (p95, p99, max) of their latencies."""
    targets = HoleTargets(pose, depth)
    solver.solve(targets.subset([0]))  # warm-up: lazy setup (RBF fit, first kernels) is not timed
    result = solver.solve(targets)
    batch_s = [result.wall_s]
    while sum(batch_s) < 1.0 and len(batch_s) < 20:  # fast solvers: median of repeats, not one noisy sample
        batch_s.append(solver.solve(targets).wall_s)
    with threads(1):
        latencies = single_latencies(solver, targets, single)[0]
    table = solution_table(pose, result.q, safety)
    row = summarize(table)
    batch = statistics.median(batch_s)
    return {
        "holes": len(targets),
        **{k: row[k] for k in ("hole_mm_mean", "hole_mm_p95", "hole_mm_max", "solved_1mm_share",
                               "collision_rate_paper", "any_violation_share")},
        "ok_share": float(((table["hole_mm"] <= OK_MM) & ~table["any_violation"]).mean()),
        "batch_ms_per_hole": 1000 * batch / len(targets), "holes_per_s": len(targets) / batch,
        "single_ms_per_hole": 1000 * statistics.median(latencies) if latencies else float("nan"),
        **{f"single_ms_{k}": 1000 * float(np.percentile(latencies, q)) if latencies else float("nan")
           for k, q in (("p95", 95), ("p99", 99), ("max", 100))},
        "single_holes": len(latencies),
        "iterations_mean": float(result.iterations.double().mean()),
    }, result


def markdown(df: pd.DataFrame) -> str:
    fmt = df.copy()
    for col in ["hole_mm_mean", "hole_mm_p95", "hole_mm_max"]:
        fmt[col] = fmt[col].map(lambda v: f"{v:.3g}" if v < 100 else f"{v:.0f}")
    for col in ["solved_1mm_share", "collision_rate_paper", "any_violation_share", "ok_share"]:
        fmt[col] = (100 * fmt[col]).map(lambda v: f"{v:.1f} %")
    for col in ["batch_ms_per_hole", "single_ms_per_hole", "single_ms_p95", "single_ms_p99", "single_ms_max"]:
        fmt[col] = fmt[col].map(lambda v: f"{v:.3g}")
    fmt["holes_per_s"] = fmt["holes_per_s"].map(lambda v: f"{v:,.0f}")
    fmt["iterations_mean"] = fmt["iterations_mean"].map(lambda v: f"{v:.1f}")
    fmt["setup_s"] = fmt["setup_s"].map(lambda v: f"{v:.1f}")
    return markdown_table(fmt)


def build_solvers(methods: list[str], specs: dict, safety, models_dir, start_box=None,
                  hybrid: HybridSettings | None = None) -> dict[str, tuple[Solver, float, int | None]]:
    """Every solver built (networks loaded, RBF fitted) before the first solve: fail early. Each
    comes with its setup time, its ``max_holes`` (None: every hole) and its ``single`` (holes timed alone;
    None: ``solver_benchmark.single``); a hybrid entry runs with
    ``hybrid`` (the ``solver`` group)."""
    unknown = [m for m in methods if m not in specs]
    if unknown:
        raise ConfigError(f"solver_benchmark.methods: {unknown} have no entry under solver_benchmark.solvers "
                          f"({sorted(specs)})")
    solvers = {}
    for m in methods:
        spec = dict(specs[m])
        cap, single = spec.pop("max_holes", None), spec.pop("single", None)
        if cap is not None and (isinstance(cap, bool) or not isinstance(cap, int) or cap < 1):
            raise ConfigError(f"solver_benchmark.solvers.{m}.max_holes = {cap!r}: expected a positive integer or null")
        if single is not None and (isinstance(single, bool) or not isinstance(single, int) or single < 0):
            raise ConfigError(f"solver_benchmark.solvers.{m}.single = {single!r}: expected a whole number >= 0 or null")
        start = time.perf_counter()
        try:
            solver = build_solver(m, spec, safety.boom, models_dir, specs, safety, start_box, hybrid)
        except PeersUnavailable as exc:  # an optional peer library: its row is left out, said once
            log.warning("benchmark: %s skipped: %s", m, exc)
            continue
        if hasattr(solver, "fit"):
            solver.fit()
        solvers[m] = (solver, time.perf_counter() - start, cap, single)
    return solvers


def benchmark_all(solvers: dict, pose: torch.Tensor, safety, settings: SolverBenchmarkSettings,
                  mlrun) -> tuple[pd.DataFrame, dict]:
    """Every solver of :func:`build_solvers` measured on ``pose`` (its first ``max_holes``); a solver that
    reports statuses is also checked against the slow reference search. Metrics go to ``mlrun``
    (anything with ``log_metrics(values, prefix=)``). Returns the table and the references by method."""
    rows, references = [], {}
    for m, (solver, setup_s, cap, single) in solvers.items():
        row, result = measure(solver, pose[:cap], safety.boom.preview_depth, safety,
                              settings.single if single is None else single)
        rows.append({"method": m, **row, "setup_s": setup_s})
        mlrun.log_metrics(row, prefix=f"{m}.")
        if result.status is not None and settings.reference_ok_sample:
            references[m] = {"statuses": dict(Counter(result.status)), **status_agreement(
                solver, pose[:cap], result.status, settings.reference_ok_sample)}
            mlrun.log_metrics({k: v for k, v in references[m].items() if isinstance(v, (int, float))},
                              prefix=f"{m}.reference.")
        log.info("%-10s %d holes: mean %.4g mm, p95 %.4g mm, ok %.2f %%, collisions %.2f %%, %.4g ms/hole "
                 "batched, single (%d holes) median %.3g / p99 %.3g ms", m, row["holes"], row["hole_mm_mean"],
                 row["hole_mm_p95"], 100 * row["ok_share"], 100 * row["collision_rate_paper"],
                 row["batch_ms_per_hole"], row["single_holes"], row["single_ms_per_hole"], row["single_ms_p99"])
    return pd.DataFrame(rows, columns=COLUMNS), references


def write_results(df: pd.DataFrame, machine: dict, out, references: dict) -> None:
    write_csv(df, out / "results.csv")
    # keyed by method so `dvc metrics show` / `dvc exp show` list one column per method and figure
    finite = lambda v: v if not isinstance(v, float) or math.isfinite(v) else None  # noqa: E731  NaN: not measured
    write_json({"machine": machine, "status_reference": references,
                **{r["method"]: {k: finite(v) for k, v in r.items() if k != "method"} for r in df.to_dict("records")}},
               out / "results.json")
    write_text(f"Test groups {machine['groups']}, first {machine['holes_per_group']} holes of each (a method's "
               f"`holes` column says how many it solved); {machine['processor']}, {machine['threads']} torch threads, "
               f"torch {machine['torch']}.\n\n" + markdown(df) + reference_markdown(references), out / "results.md")
    save_figure(error_vs_time(df), out / "figures" / "error_vs_time.png")


def reference_markdown(references: dict) -> str:
    lines = []
    for m, r in references.items():
        lines += ["", f"{m}: statuses {r['statuses']}. Reference search (pipeline/evaluation/status_reference.py) on "
                  f"{r['holes_checked']} holes (every hole not ok, {r['ok_sampled']} ok ones sampled): agreement "
                  f"{100 * r['agreement']:.1f} %, {r['fast_not_ok_that_reference_solves']} not-ok holes the reference "
                  f"solves, {r['no_clear_solution_found_by_reference']} with no clear solution found; pairs "
                  f"(fast->reference) {r['pairs']}.", ""]
    return "\n".join(lines)
