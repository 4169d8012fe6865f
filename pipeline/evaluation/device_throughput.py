"""The hybrid solver's throughput on one device at growing batch sizes.

For each size ``N`` the holes are drawn like the study's test groups (:func:`sample_holes`, a seed per
size), solved once untimed (the device's first kernels, cuBLAS/cuSOLVER handles and the caching
allocator's first blocks are set up there), then solved ``repeats`` times; holes/s is ``N`` over the
median wall time, taken after the device has finished (``torch.cuda.synchronize``). Every answer is
judged again from its joints by forward kinematics and the safety model (:func:`solution_table`), not
by the solver's own statuses: ``ok`` is the benchmark's one rule (:func:`~pipeline.evaluation.peer_timing.judge`:
a hole-seeking error <= 0.01 mm, within the joint ranges, no violation), and
``ok_but_bad`` counts holes the solver called ``ok`` that this check does not (it must be 0).

Holes are solved in chunks of at most ``chunk`` (one call each) so the peak memory stays bounded; the
chunks run one after another on the one device.
"""

from __future__ import annotations

import statistics
import time
from collections import Counter
from dataclasses import dataclass

import torch

from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.evaluation.metrics import solution_table
from pipeline.evaluation.peer_timing import judge_table
from pipeline.geometry.collision import SafetyModel
from pipeline.solvers.base import HoleTargets, Solver

COLUMNS = ("device", "solver", "holes", "chunk", "holes_per_s", "wall_s_median", "wall_s_min", "ok_share",
           "ok_but_bad", "statuses", "hole_mm_mean", "hole_mm_p95", "hole_mm_max_ok", "peak_gib", "repeat_identical")


@dataclass(frozen=True)
class ThroughputRow:
    """One size on one device: speed, and the answers judged from their joints."""

    device: str
    solver: str
    holes: int
    chunk: int
    holes_per_s: float
    wall_s_median: float
    wall_s_min: float
    ok_share: float
    ok_but_bad: int
    statuses: dict
    hole_mm_mean: float
    hole_mm_p95: float
    hole_mm_max_ok: float
    peak_gib: float | None  # None off CUDA
    repeat_identical: bool  # every timed solve gave the first one's joints and statuses, to the bit

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in COLUMNS}


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def solve_in_chunks(solver: Solver, pose: torch.Tensor, depth: float, chunk: int) -> tuple[torch.Tensor, list[str]]:
    """Joints ``(N, n)`` and statuses of ``pose (N, 6)``, solved ``chunk`` holes per call."""
    qs, statuses = [], []
    for lo in range(0, len(pose), chunk):
        res = solver.solve(HoleTargets(pose[lo:lo + chunk], depth))
        qs.append(res.q)
        statuses += res.status if res.status is not None else ["?"] * len(res.q)
    return torch.cat(qs), statuses


def measure_size(solver: Solver, safety: SafetyModel, sampling: HoleSampling, n: int, seed: int,
                 device: torch.device, repeats: int, chunk: int) -> ThroughputRow:
    """One row: ``n`` holes drawn with ``seed``, moved to ``device``, solved untimed once, then timed."""
    pose, _ = sample_holes(n, safety, sampling, seed)
    pose = pose.to(device)
    depth = safety.boom.preview_depth
    chunk = min(chunk, n)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    q, statuses = solve_in_chunks(solver, pose, depth, chunk)  # untimed: first kernels and allocations
    walls, identical = [], True
    for _ in range(repeats):
        _sync(device)
        start = time.perf_counter()
        q2, statuses2 = solve_in_chunks(solver, pose, depth, chunk)
        _sync(device)
        walls.append(time.perf_counter() - start)
        identical &= statuses2 == statuses and torch.equal(q2, q)
    table = solution_table(pose, q, safety)  # judged again from the joints, on the same device
    hole_mm = torch.tensor(table["hole_mm"].to_numpy())
    solved, violates = judge_table(table)
    good = solved & ~violates
    said_ok = torch.tensor([s == "ok" for s in statuses])
    median = statistics.median(walls)
    peak = torch.cuda.max_memory_allocated(device) / 2**30 if device.type == "cuda" else None
    return ThroughputRow(
        device=str(device), solver=solver.name, holes=n, chunk=chunk, holes_per_s=n / median,
        wall_s_median=median, wall_s_min=min(walls), ok_share=float(good.double().mean()),
        ok_but_bad=int((said_ok & ~good).sum()), statuses=dict(Counter(statuses)),
        hole_mm_mean=float(hole_mm.mean()), hole_mm_p95=float(hole_mm.quantile(0.95)),
        hole_mm_max_ok=float(hole_mm[good].max()) if bool(good.any()) else float("nan"), peak_gib=peak,
        repeat_identical=bool(identical))


def markdown_table(rows: list[dict]) -> str:
    """The rows as the docs' table."""
    head = ("| device | solver | holes | chunk | holes / s | wall (s) | ok | ok but not by the check | "
            "mean / p95 hole error (mm) | worst ok (mm) | peak GPU memory (GiB) |")
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        lines.append(f"| {r['device']} | {r['solver']} | {r['holes']:,} | {r['chunk']:,} | {r['holes_per_s']:,.0f} | "
                     f"{r['wall_s_median']:.3f} | {100 * r['ok_share']:.3f} % | {r['ok_but_bad']} | "
                     f"{r['hole_mm_mean']:.3g} / {r['hole_mm_p95']:.3g} | {r['hole_mm_max_ok']:.3g} | "
                     f"{'-' if r['peak_gib'] is None else format(r['peak_gib'], '.2f')} |")
    return "\n".join(lines) + "\n"
