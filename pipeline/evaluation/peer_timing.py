"""Single-hole latency and batched throughput of any solver, with every answer judged by the
project's safety model: the figures the benchmark sets side by side for the project's solvers and
the peer libraries (pipeline/solvers/peers.py).

Plain functions, no stage: the benchmark (or a one-off script) builds the solvers and the holes and
calls :func:`time_solver` for each. Timings are wall clock on whatever else the machine is doing:
compare solvers within one run.
"""

from __future__ import annotations

import gc
import statistics
import time
from contextlib import contextmanager

import torch

from pipeline.evaluation.metrics import solution_table
from pipeline.solvers.base import HoleTargets, Solver

OK_MM = 0.01  # the benchmark's ok rule: hole-seeking error <= 0.01 mm and no safety violation


@contextmanager
def threads(n: int):
    """Run with ``n`` torch threads and, where numba is loaded, ``n`` numba threads (restored after)."""
    import numba

    old_torch, old_numba = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(n)
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        torch.set_num_threads(old_torch)
        numba.set_num_threads(old_numba)


def judge(pose: torch.Tensor, q: torch.Tensor, safety) -> tuple[torch.Tensor, torch.Tensor]:
    """Per hole: solved (<= 0.01 mm and in the joint ranges) and violating a safety distance, from the
    joints alone (the project's FK and safety model): the same rule for every solver."""
    return judge_table(solution_table(pose, q, safety))


def judge_table(table) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`judge` of a :func:`solution_table` already made (its ``within_limits`` column is the boom's
    range check of the same joints)."""
    solved = torch.tensor(((table["hole_mm"] <= OK_MM) & table["within_limits"]).to_numpy())
    return solved, torch.tensor(table["any_violation"].to_numpy())


def shares(solved: torch.Tensor, violates: torch.Tensor) -> dict[str, float]:
    return {"solved_share": float(solved.double().mean()), "violation_share": float(violates.double().mean()),
            "ok_share": float((solved & ~violates).double().mean())}


def single_latencies(solver: Solver, targets: HoleTargets, n: int) -> tuple[list[float], torch.Tensor]:
    """Wall seconds of ``n`` one-hole solves (the first ``n`` holes, each alone) and their joints.

    Python's garbage collector is run before and held off during the loop, as ``timeit`` does: a full
    collection walks the whole process's heap (torch, pandas, MLflow, the other solvers), so the pause
    it adds to one hole's time measures the process, not the solver (a controller freezes or schedules
    its collections)."""
    out, qs = [], []
    gc.collect()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        for i in range(min(n, len(targets))):
            one = targets.subset([i])
            start = time.perf_counter()
            res = solver.solve(one)
            out.append(time.perf_counter() - start)
            qs.append(res.q)
    finally:
        if was_enabled:
            gc.enable()
    return out, torch.cat(qs)


def batch_seconds(solver: Solver, targets: HoleTargets, min_total_s: float = 1.0, max_repeats: int = 20):
    """Median wall seconds of solving every hole in one call (repeated up to ``min_total_s``), and
    the result of a first, untimed call. A peer without batches loops inside its own ``solve``."""
    first = solver.solve(targets)  # not timed: a batch may call what one hole did not (kernels, stages)
    times = []
    while not times or (sum(times) < min_total_s and len(times) < max_repeats):
        start = time.perf_counter()
        solver.solve(targets)
        times.append(time.perf_counter() - start)
    return statistics.median(times), first


def time_solver(solver: Solver, pose: torch.Tensor, safety, single: int = 200, single_threads: int = 1,
                batch_threads: int = 2, batch: bool = True) -> dict:
    """One row: median ms for one hole (``single`` holes, each alone, ``single_threads``), holes/s of
    one batch of every hole (``batch_threads``; ``batch=False`` skips it), and the ok shares of the
    batch's answers (of the single answers without a batch), all judged by :func:`judge`."""
    targets = HoleTargets(pose, safety.boom.preview_depth)
    solver.solve(targets.subset([0]))  # warm-up: lazy set-up and first calls are not timed
    with threads(single_threads):
        lat, q_single = single_latencies(solver, targets, single)
    row = {"method": solver.name, "holes": len(pose), "single_ms_median": 1000 * statistics.median(lat),
           "single_ms_p95": 1000 * sorted(lat)[int(0.95 * (len(lat) - 1))], "single_holes": len(lat)}
    if batch:
        with threads(batch_threads):
            seconds, result = batch_seconds(solver, targets)
        solved, violates = judge(pose, result.q, safety)
        row["holes_per_s"] = len(pose) / seconds
        if result.status is not None:  # a solver that reports statuses: its ok holes, checked independently
            said_ok = torch.tensor([s == "ok" for s in result.status])
            row["statuses"] = {s: result.status.count(s) for s in sorted(set(result.status))}
            row["said_ok_but_not"] = int((said_ok & (violates | ~solved)).sum())
    else:
        solved, violates = judge(pose[:len(lat)], q_single, safety)
        row["holes_per_s"] = len(lat) / sum(lat)
    return row | shares(solved, violates)
