"""Two measurements of a rig on a plan (docs/rig.md, docs/benchmarks.md):

* :func:`redundancy` -- what the boom's redundancy saves in move time. Each boom takes the holes it can
  drill (ok in the reach table) in the plan's order, from its park. *Independent* solutions are the reach
  table's (each hole on its own: the largest clearance). *Chained* ones solve each hole from the previous
  hole's joints (the first from park) with the hybrid's ``prefer: start``, so among the hole's ok
  solutions the one nearest the previous one is kept. Both sums use the reference's synchronised move time
  (:func:`pipeline.motion.timing.move_time`) between consecutive configurations, park -> first -> ... ->
  last; they time straight joint-space moves, not checked ones (the move benchmark checks moves).
  *Nearest* keeps, per hole, whichever of the two (chained, independent) is the quicker move from the
  previous kept one: the chained answer alone drifts in the null space (each LM step is the least-norm
  step in joint units, not in move time), so the nearest of both is what redundancy is worth here.
* :func:`move_benchmark` -- collision-free moves (:func:`pipeline.motion.moves.plan_move`) between random
  pairs of a boom's holes, every other boom standing at a random ok hole of its own. Both ends are first
  solved given where the others stand (the hybrid's boom-boom rows, from the reach table's joints); a pair
  whose ends cannot be made ok there is counted as ``blocked`` (no move can start or end there), the
  others as straight, retract, planned or failed. Plus boom-boom distance evaluations per second, batched.

Seeded throughout: the same settings give the same pairs and stands.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch

from pipeline.core.settings import rule
from pipeline.geometry.boom_pair import BoomPair
from pipeline.geometry.rig import Rig
from pipeline.motion.moves import KINDS, PlannerSettings, plan_move
from pipeline.motion.timing import JointLimits, move_time
from pipeline.plans.model import DrillPlan
from pipeline.plans.reach import Reach, parked_others
from pipeline.solvers.base import HoleTargets
from pipeline.solvers.hybrid import BoomObstacle, HybridSolver

D = torch.float64
OMPL_SEED_MAX = 2**31 - 1  # OMPL's seed is 32-bit (as round's detour_seed); bounds: conf/move_benchmark/default.yaml
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MoveBenchmarkSettings:
    """The ``move_benchmark`` node (conf/move_benchmark/default.yaml)."""

    # random hole pairs per boom (the issue asks 1000)
    pairs: int = field(default=100, metadata=rule(ge=1, le=100_000))
    seed: int = field(default=0, metadata=rule(ge=0, le=OMPL_SEED_MAX))
    # OMPL's budget per move as counts (the same pairs give the same paths on any machine); the wall-time
    # budgets replace them only when set (interactive use: then results depend on the machine's load)
    planner_iterations: int = field(default=5000, metadata=rule(ge=1, le=1_000_000))
    simplify_steps: int = field(default=40, metadata=rule(ge=0, le=10_000))
    planner_time_s: float | None = field(default=None, metadata=rule(gt=0, le=3600))
    simplify_s: float | None = field(default=None, metadata=rule(gt=0, le=3600))
    # configuration pairs per boom-boom call
    distance_batch: int = field(default=4096, metadata=rule(ge=1, le=65_536))
    distance_repeats: int = field(default=20, metadata=rule(ge=1, le=10_000))


def _ok_rows(reach: Reach, name: str) -> pd.DataFrame:
    t = reach.table
    return t[(t["boom"] == name) & (t["status"] == "ok")]


def _joints(rows: pd.DataFrame, rig: Rig, index: int) -> torch.Tensor:
    return torch.tensor(rows[rig.booms[index].boom.joint_names].to_numpy(), dtype=D)


def path_time(q: torch.Tensor, limits: JointLimits) -> float:
    """Summed synchronised move time (s) along the configurations ``q (K, n)``, in order."""
    return float(move_time(q[:-1], q[1:], limits).sum()) if len(q) > 1 else 0.0


def _saved(reference: float, t: float) -> float:
    return 100 * (reference - t) / reference if reference else 0.0


def redundancy(rig: Rig, plan: DrillPlan, reach: Reach, solvers: list[HybridSolver],
               limits: list[JointLimits]) -> pd.DataFrame:
    """Per boom: its ok holes in plan order, the summed move time with independent and chained solutions,
    and how many chained holes were not ok (those keep their independent solution in the chained sum)."""
    rows = []
    poses = plan.poses(rig.booms[0].boom.preview_depth)
    index_of = {h: k for k, h in enumerate(plan.holes["hole_id"])}
    for i, (mount, solver) in enumerate(zip(rig.booms, solvers, strict=True)):
        ok = _ok_rows(reach, mount.name)
        independent = _joints(ok, rig, i)
        chainer = HybridSolver(mount.boom, mount.safety, None, dataclasses.replace(solver.s, prefer="start"),
                               f"chained[{mount.name}]", (solver.space.full(solver.start_lo[None])[0],
                                                          solver.space.full(solver.start_hi[None])[0]),
                               base=mount.base)
        others = parked_others(rig, i)
        started = time.perf_counter()
        chained, nearest, not_ok = [], [], 0
        for chain, pick_nearest in ((chained, False), (nearest, True)):
            previous = mount.park
            for k, hole in enumerate(ok["hole_id"]):  # sequential by nature: each start is the previous answer
                targets = HoleTargets(poses[[index_of[hole]]], mount.boom.preview_depth)
                res = chainer.solve(targets, obstacles=others, start=previous)
                answer = res.q[0] if res.status[0] == "ok" else independent[k]
                not_ok += res.status[0] != "ok" and not pick_nearest
                if pick_nearest and move_time(previous, independent[k], limits[i]) < move_time(previous, answer,
                                                                                                limits[i]):
                    answer = independent[k]
                chain.append(answer)
                previous = answer
        wall = time.perf_counter() - started
        park = mount.park[None]
        t_ind = path_time(torch.cat([park, independent]), limits[i])
        t_ch = path_time(torch.cat([park, torch.stack(chained)]), limits[i])
        t_near = path_time(torch.cat([park, torch.stack(nearest)]), limits[i])
        rows.append({"boom": mount.name, "holes": len(ok), "independent_move_s": t_ind, "chained_move_s": t_ch,
                     "chained_saved_pct": _saved(t_ind, t_ch), "nearest_move_s": t_near,
                     "nearest_saved_pct": _saved(t_ind, t_near),
                     "chained_not_ok": int(not_ok), "solve_s": wall})
    return pd.DataFrame(rows)


def distance_rate(rig: Rig, settings: MoveBenchmarkSettings) -> dict[str, float]:
    """Boom-boom clearances per second of booms 0 and 1, batched: from frames given, and with both booms'
    forward kinematics included (random joints within the ranges)."""
    a, b = rig.booms[0], rig.booms[1]
    pair = BoomPair(a.boom, b.boom, rig.d_boom)
    g = torch.Generator().manual_seed(settings.seed)
    n = settings.distance_batch

    def joints(m):
        lo, hi = m.boom.limits(D)
        return m.boom.with_locks(lo + (hi - lo) * torch.rand(n, m.boom.n_joints, generator=g, dtype=D))

    qa, qb = joints(a), joints(b)
    with torch.inference_mode():
        fa, fb = a.frames(qa), b.frames(qb)
        pair.clearance(fa, fb)  # warm-up
        t0 = time.perf_counter()
        for _ in range(settings.distance_repeats):
            pair.clearance(fa, fb)
        t1 = time.perf_counter()
        for _ in range(settings.distance_repeats):
            pair.clearance(a.frames(qa), b.frames(qb))
        t2 = time.perf_counter()
    total = n * settings.distance_repeats
    return {"boom_pairs_per_s": total / (t1 - t0), "boom_pairs_per_s_with_fk": total / (t2 - t1),
            "distance_batch": n, "threads": torch.get_num_threads()}


def move_benchmark(rig: Rig, plan: DrillPlan, reach: Reach, solvers: list[HybridSolver], limits: list[JointLimits],
                   settings: MoveBenchmarkSettings) -> tuple[pd.DataFrame, dict]:
    """``settings.pairs`` random moves per boom; returns one row per pair and the summary."""
    g = np.random.default_rng(settings.seed)
    poses = plan.poses(rig.booms[0].boom.preview_depth)
    index_of = {h: k for k, h in enumerate(plan.holes["hole_id"])}
    planner = PlannerSettings(iterations=settings.planner_iterations, simplify_steps=settings.simplify_steps,
                              time_s=settings.planner_time_s, simplify_s=settings.simplify_s, seed=settings.seed)
    records, started = [], time.perf_counter()
    for i, (mount, solver) in enumerate(zip(rig.booms, solvers, strict=True)):
        ok = _ok_rows(reach, mount.name)
        holes, q_reach = ok["hole_id"].tolist(), _joints(ok, rig, i)
        P = settings.pairs
        ab = np.stack([g.choice(len(holes), 2, replace=False) for _ in range(P)])
        stands = {}
        for j, other in enumerate(rig.booms):
            if j != i:
                their = _ok_rows(reach, other.name)
                pick = g.integers(len(their), size=P)
                stands[j] = (_joints(their, rig, j)[pick], their["hole_id"].to_numpy()[pick])
        # both ends solved given where the others stand, from the reach table's joints, in one batch
        ends = torch.as_tensor(ab.T.reshape(-1))  # all a's, then all b's
        targets = HoleTargets(poses[[index_of[holes[k]] for k in ends.tolist()]], mount.boom.preview_depth)
        obstacles = [BoomObstacle(BoomPair(mount.boom, rig.booms[j].boom, rig.d_boom),
                                  rig.booms[j].frames(q.repeat(2, 1)), rig.booms[j].name)
                     for j, (q, _) in stands.items()]
        solved = solver.solve(targets, obstacles=obstacles, start=q_reach[ends])
        q_end = solved.q.reshape(2, P, -1)
        end_ok = np.array([s == "ok" for s in solved.status]).reshape(2, P).all(0)
        for p in range(P):
            if p and p % 50 == 0:
                log.info("boom %s: %d of %d pairs (%.0f s)", mount.name, p, P, time.perf_counter() - started)
            rec = {"boom": mount.name, "from": holes[ab[p, 0]], "to": holes[ab[p, 1]],
                   **{f"stand_{rig.booms[j].name}": ids[p] for j, (_, ids) in stands.items()}}
            if not end_ok[p]:
                records.append({**rec, "kind": "blocked", "duration_s": math.nan, "planning_s": 0.0})
                continue
            move = plan_move(rig, i, q_end[0, p], q_end[1, p], limits[i],
                             others={j: q[p] for j, (q, _) in stands.items()}, planner=planner)
            records.append({**rec, "kind": move.kind, "duration_s": move.duration if move.clear else math.nan,
                            "planning_s": move.planning_s, **{f"min_{k}_m": v for k, v in move.clearances.items()},
                            "reason": move.reason})
    table = pd.DataFrame(records)
    return table, summarise(table, rig)


def summarise(table: pd.DataFrame, rig: Rig) -> dict:
    """Shares of each kind among moves attempted (blocked pairs apart), median / p95 move time of the clear
    ones, planning time per move; per boom and over all."""
    out: dict = {}
    for name, t in [("all", table), *((b, table[table["boom"] == b]) for b in rig.names)]:
        tried = t[t["kind"] != "blocked"]
        out[f"{name}.pairs"] = len(t)
        out[f"{name}.blocked"] = int((t["kind"] == "blocked").sum())
        out[f"{name}.moves"] = len(tried)
        for kind in (*KINDS, "failed"):
            out[f"{name}.{kind}_share"] = float((tried["kind"] == kind).mean()) if len(tried) else math.nan
        clear = tried["duration_s"].dropna()
        out[f"{name}.move_s_median"] = float(clear.median()) if len(clear) else math.nan
        out[f"{name}.move_s_p95"] = float(clear.quantile(0.95)) if len(clear) else math.nan
        out[f"{name}.planning_s_mean"] = float(tried["planning_s"].mean()) if len(tried) else math.nan
        out[f"{name}.planning_s_median"] = float(tried["planning_s"].median()) if len(tried) else math.nan
        out[f"{name}.planning_s_p95"] = float(tried["planning_s"].quantile(0.95)) if len(tried) else math.nan
    return out
