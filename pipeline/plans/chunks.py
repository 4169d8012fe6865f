"""Solving a plan in chunks: memory bounded by the chunk, not the plan, with progress for long plans."""

from __future__ import annotations

import logging
import sys
import time

import torch

from pipeline.core.errors import ConfigError
from pipeline.solvers.base import HoleTargets, SolveResult

log = logging.getLogger(__name__)

PROGRESS_AFTER_S = 3.0  # a plan solved faster than this shows no progress at all


def solve_in_chunks(solver, pose: torch.Tensor, depth: float, chunk: int, progress: bool = True) -> SolveResult:
    """``solver.solve`` on ``chunk`` holes at a time; the results joined in order. The solver's
    working memory (Jacobians, clearances, its restarts) is per chunk, so a plan of 1e5 holes needs
    what a plan of ``chunk`` holes needs, plus the small per-hole results. Progress: a tqdm bar on a
    terminal, else a log line per chunk, once the plan has taken ``PROGRESS_AFTER_S``."""
    from tqdm import tqdm

    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ConfigError(f"solve.chunk = {chunk!r}: expected a positive number of holes")
    n = len(pose)
    parts: list[SolveResult] = []
    start = time.perf_counter()
    tty = sys.stderr.isatty()
    with tqdm(total=n, unit="hole", desc="solve", delay=PROGRESS_AFTER_S, disable=not (progress and tty),
              file=sys.stderr) as bar:
        for i in range(0, n, chunk):
            parts.append(solver.solve(HoleTargets(pose[i : i + chunk], depth)))
            bar.update(len(parts[-1].q))
            elapsed = time.perf_counter() - start
            done = min(i + chunk, n)
            if progress and not tty and elapsed > PROGRESS_AFTER_S and done < n:
                log.info("solve: %d/%d holes (%.0f %%), %.0f s elapsed, ~%.0f s left", done, n, 100 * done / n,
                         elapsed, elapsed * (n - done) / done)
    return join_results(parts)


def join_results(parts: list[SolveResult]) -> SolveResult:
    """Results of consecutive chunks as one (wall time: the sum)."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    return SolveResult(
        torch.cat([p.q for p in parts]),
        {k: torch.cat([p.errors[k] for p in parts]) for k in first.errors},
        torch.cat([p.iterations for p in parts]),
        sum(p.wall_s for p in parts),
        status=None if first.status is None else [s for p in parts for s in p.status],
        clearances=None if first.clearances is None else {k: torch.cat([p.clearances[k] for p in parts])
                                                          for k in first.clearances},
    )
