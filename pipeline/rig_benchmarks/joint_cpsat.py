"""The round as one CP-SAT model: allocation, order and timing together ("Measure, then choose").

A measurement against the routing (:mod:`pipeline.round.routing`), not the planner: nothing of the stage
calls it (docs/benchmarks.md, "Joint CP-SAT model against the routing").

**The model** (integer milliseconds). Per boom b one circuit (``AddCircuit``) over a depot (where b
starts, its park unless handed on, and its park at the end) and the holes b can reach: arc literals
``x[b, u, v]``; a hole off b's circuit takes its self-loop, ``not on[b, h]``; the depot's self-loop is
an unused boom. Every drillable hole is on exactly one boom that reaches it. Per hole, ``start[h]``
(the boom arrives and drills) and ``leave[h]`` (it moves on), ``leave - start >= drill_s``. An arc
u -> v of boom b forces ``start[v] == leave[u] + move_s[b, u, v]``: an equality, so a boom that waits
stands at u, as the timeline has it (:mod:`pipeline.round.timeline`: a wait is a later start of a
move), and ``[start, leave]`` is exactly where it stands at the hole. From the depot ``start[v] >=
move`` (waiting at park is free), into it ``end[b] >= leave[u] + move``. Per (hole, boom) an optional
interval ``[start, leave]``, present when the hole is on that boom; for every pair (i on a, j on b,
a != b) whose standing configurations conflict (the oracle's standing clearance below 0:
:meth:`pipeline.round.oracle.KinematicOracle.standing`), a no-overlap of the two. Precedence:
``start[j] >= start[i] + drill[i]``. Objective: the makespan, the latest ``end[b]``. Redundant, for
the bound: each boom's drilling plus its moves fit in the makespan (the LP then sees the loads).

**What it does not know**: conflicts while a boom moves, the detours' durations (straight moves) and
the moves another boom at park blocks. So its routes are timed by the planner's own timeline
(:func:`pipeline.round.planner.timed_routes`: moves certified, move conflicts waited for), and that
makespan, not the objective, is what compares with the routing.

**Hint**: routes (the planner's sweep) timed by the timeline with standing conflicts only
(:class:`StandingOracle`) on the model's own millisecond durations, so the hint is a complete and
feasible assignment. **Deterministic**: one worker, a fixed seed, stopped by
``max_deterministic_time``; ``max_time_in_seconds`` is opt-in, for runs at equal wall time.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.settings import rule
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline, resolve

MS = 1000  # the model's unit: milliseconds


@dataclass(frozen=True)
class JointSettings:
    max_deterministic_time: float | None = field(default=10.0, metadata=rule(gt=0))
    max_time_in_seconds: float | None = field(default=None, metadata=rule(gt=0))  # opt-in: not reproducible
    random_seed: int = field(default=0, metadata=rule(ge=0))
    num_workers: int = field(default=1, metadata=rule(ge=1))
    interleave: bool = True  # CP-SAT's portfolio (LNS included) on one thread, deterministic: interleave_search
    log: bool = False


@dataclass(frozen=True)
class JointResult:
    routes: list[list[int]] | None  # per boom, holes in drilling order (None: no solution found)
    start_s: np.ndarray  # (H,) when each hole's drilling starts (NaN: not drilled)
    leave_s: np.ndarray  # (H,) when its boom moves on
    makespan_s: float | None  # the model's objective (standing conflicts and straight moves only)
    bound_s: float  # the solver's lower bound of the objective: a certificate
    status: str
    wall_s: float
    deterministic_time: float
    pairs: int  # standing-conflict pairs in the model
    arcs: int


def standing_conflicts(oracle, reach: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """``(a, b) -> (H, H)`` bool, a < b: boom a standing at hole i and boom b at hole j break d_boom
    (the oracle's standing clearance below 0, as its check reads it), holes each can reach only."""
    B, H = reach.shape
    return {(a, b): (oracle.standing(a, b)[:H, :H] < 0) & reach[a][:, None] & reach[b][None, :]
            for a in range(B) for b in range(a + 1, B)}


class StandingOracle:
    """A conflict oracle of standing pairs only (``conflicts`` of :func:`standing_conflicts`): moves
    never conflict. What the joint model knows, so a timeline under it is one of the model's answers."""

    def __init__(self, conflicts: Mapping[tuple[int, int], np.ndarray]):
        self.conflicts = conflicts

    def check(self, a, seg_a, b, seg_b, lo, hi):
        table = self.conflicts.get((a, b))
        hit = np.zeros(len(lo), bool)
        if table is not None:
            H = table.shape[0]
            ua, ub = np.asarray(seg_a["u"]), np.asarray(seg_b["u"])
            still = (ua == np.asarray(seg_a["v"])) & (ub == np.asarray(seg_b["v"])) & (ua < H) & (ub < H)
            hit[still] = table[ua[still], ub[still]]
        return np.where(hit, lo, np.inf), np.where(hit, -1.0, 1.0)


def in_ms(inst: Instance) -> Instance:
    """``inst`` with drilling and moves rounded to whole milliseconds (the model's data), so a timeline
    of it converts to integers exactly."""
    drill = np.round(inst.drill_s * MS) / MS
    phases = np.stack([drill, np.zeros_like(drill), np.zeros_like(drill)], axis=-1)
    move = np.where(np.isfinite(inst.move_s), np.round(np.nan_to_num(inst.move_s, posinf=0.0) * MS) / MS, inst.move_s)
    return dataclasses.replace(inst, phases=phases, move_s=move)


def hint_timeline(inst: Instance, routes: list[list[int]], conflicts) -> Timeline:
    """``routes`` timed on :func:`in_ms` durations with waits for standing conflicts only."""
    return resolve(in_ms(inst), routes, StandingOracle(conflicts), max_repairs=10 * inst.n_holes + 100)


def joint_round(inst: Instance, conflicts, settings: JointSettings = JointSettings(),
                hint: list[list[int]] | None = None) -> JointResult:
    """:func:`solve_joint` on an instance; ``hint``: routes, timed by :func:`hint_timeline`."""
    tl = None if hint is None else hint_timeline(inst, hint, conflicts)
    return solve_joint(inst.reach, inst.drill_s, inst.move_s, conflicts, inst.precedence, inst.starts, tl, settings)


def solve_joint(reach: np.ndarray, drill_s: np.ndarray, move_s: np.ndarray,
                conflicts: Mapping[tuple[int, int], np.ndarray], precedence: Sequence[tuple[int, int]] = (),
                starts: Sequence[int] | None = None, hint: Timeline | None = None,
                settings: JointSettings = JointSettings()) -> JointResult:
    """The joint model (module docstring) of ``reach (B, H)``, ``drill_s (H,)``, ``move_s (B, H + 1,
    H + 1)`` (index H: park) and ``conflicts`` ((a, b) -> (H, H) bool, a < b); ``starts``: each boom's
    start node (None: parks); ``hint``: a timeline of the same durations in whole ms. Holes no boom
    reaches are left out."""
    from ortools.sat.python import cp_model

    t0 = time.perf_counter()
    reach = np.asarray(reach, bool)
    B, H = reach.shape
    starts = [H] * B if starts is None else [int(s) for s in starts]
    drill = np.round(np.asarray(drill_s, float) * MS).astype(np.int64)
    move = np.round(np.nan_to_num(np.asarray(move_s, float), posinf=0.0) * MS).astype(np.int64)
    holes = np.flatnonzero(reach.any(0))
    horizon = int(2 * (drill[holes].sum() + (len(holes) + 2 * B) * move.max(initial=0)) + 1)
    m = cp_model.CpModel()
    start = {h: m.new_int_var(0, horizon, f"s{h}") for h in holes}
    leave = {h: m.new_int_var(0, horizon, f"l{h}") for h in holes}
    stand = {h: m.new_int_var(int(drill[h]), horizon, f"d{h}") for h in holes}  # at the hole: drilling, then waiting
    end = [m.new_int_var(0, horizon, f"end{b}") for b in range(B)]
    makespan = m.new_int_var(0, horizon, "makespan")
    on = {(b, h): m.new_bool_var(f"on{b}_{h}") for b in range(B) for h in np.flatnonzero(reach[b])}
    interval = {(b, h): m.new_optional_interval_var(start[h], stand[h], leave[h], lit, f"i{b}_{h}")
                for (b, h), lit in on.items()}
    for h in holes:
        m.add_exactly_one(on[b, h] for b in range(B) if reach[b, h])
        m.add(leave[h] == start[h] + stand[h])
    arcs: dict[tuple[int, int, int], cp_model.IntVar] = {}  # (b, u, v), depot = -1
    unused = [m.new_bool_var(f"unused{b}") for b in range(B)]
    for b in range(B):
        mine = [int(h) for h in np.flatnonzero(reach[b])]
        node = {h: k + 1 for k, h in enumerate(mine)}  # circuit node 0: the depot
        circuit = [(0, 0, unused[b])]
        for u in mine:
            circuit.append((node[u], node[u], ~on[b, u]))
            for v in [-1, *mine]:
                if v != u:
                    arcs[b, u, v] = m.new_bool_var(f"x{b}_{u}_{v}")
                    circuit.append((node[u], node.get(v, 0), arcs[b, u, v]))
            arcs[b, -1, u] = m.new_bool_var(f"x{b}_d_{u}")
            circuit.append((0, node[u], arcs[b, -1, u]))
        m.add_circuit(circuit)
        s = starts[b]
        for u in mine:
            m.add(start[u] >= int(move[b, s, u])).only_enforce_if(arcs[b, -1, u])
            m.add(end[b] >= leave[u] + int(move[b, u, H])).only_enforce_if(arcs[b, u, -1])
            for v in mine:
                if v != u:
                    m.add(start[v] == leave[u] + int(move[b, u, v])).only_enforce_if(arcs[b, u, v])
        m.add(end[b] >= int(move[b, s, H])).only_enforce_if(unused[b])  # a boom handed on still goes home
        if s < H and reach[b, s]:  # standing at a hole not drilled yet: drills it first (the routing's rule)
            m.add(arcs[b, -1, s] == 1)
        load = [int(drill[h]) * on[b, h] for h in mine]
        load += [int(move[b, s if u < 0 else u, H if v < 0 else v]) * lit
                 for (bb, u, v), lit in arcs.items() if bb == b]
        m.add(sum(load) <= makespan)  # redundant: the boom's work fits in the makespan
    m.add_max_equality(makespan, end)
    for i, j in precedence:
        if i in start and j in start:
            m.add(start[j] >= start[i] + int(drill[i]))
    pairs = 0
    for (a, b), table in conflicts.items():
        for i, j in zip(*np.nonzero(np.asarray(table, bool)), strict=True):
            if i != j and (a, i) in interval and (b, j) in interval:
                m.add_no_overlap([interval[a, i], interval[b, j]])
                pairs += 1
    m.minimize(makespan)
    if hint is not None:
        _hint(m, hint, start, leave, stand, end, makespan, on, arcs, unused, H)
    solver = cp_model.CpSolver()
    p = solver.parameters
    p.num_workers, p.random_seed, p.log_search_progress = settings.num_workers, settings.random_seed, settings.log
    p.catch_sigint_signal = False  # Ctrl-C reaches the caller (else CP-SAT eats it, then the process exits 130)
    p.interleave_search = settings.interleave  # one worker alone runs no LNS, which is what improves a hint
    if settings.max_deterministic_time is not None:
        p.max_deterministic_time = settings.max_deterministic_time
    if settings.max_time_in_seconds is not None:
        p.max_time_in_seconds = max(0.1, settings.max_time_in_seconds - (time.perf_counter() - t0))  # build counts
    status = solver.solve(m)
    found = status in (cp_model.OPTIMAL, cp_model.FEASIBLE)
    st, lv = np.full(H, np.nan), np.full(H, np.nan)
    routes = None
    if found:
        succ = {(b, u): v for (b, u, v), lit in arcs.items() if solver.boolean_value(lit)}
        routes = []
        for b in range(B):
            r, u = [], succ.get((b, -1), -1)
            while u >= 0:
                r.append(u)
                u = succ[b, u]
            routes.append(r)
        for h in holes:
            st[h], lv[h] = solver.value(start[h]) / MS, solver.value(leave[h]) / MS
    return JointResult(routes, st, lv, solver.objective_value / MS if found else None,
                       solver.best_objective_bound / MS, solver.status_name(status), time.perf_counter() - t0,
                       solver.deterministic_time, pairs, len(arcs))


def _hint(m, tl: Timeline, start, leave, stand, end, makespan, on, arcs, unused, H: int) -> None:
    """Every variable's value in timeline ``tl`` (times in whole ms: :func:`in_ms`)."""
    ms = lambda t: int(round(float(t) * MS))  # noqa: E731
    used = set()
    for b, route in enumerate(tl.routes):
        m.add_hint(unused[b], not route)
        nodes = [-1, *route, -1]
        for u, v in zip(nodes[:-1], nodes[1:], strict=True):
            if (b, u, v) in arcs:
                used.add((b, u, v))
        for k, h in enumerate(route):
            m.add_hint(start[h], ms(tl.arrive[b][k]))
            m.add_hint(leave[h], ms(tl.move_start[b][k + 1]))
            m.add_hint(stand[h], ms(tl.move_start[b][k + 1]) - ms(tl.arrive[b][k]))
        m.add_hint(end[b], ms(tl.arrive[b][-1]))
    drilled = {(b, h) for b, r in enumerate(tl.routes) for h in r}
    for key, lit in on.items():
        m.add_hint(lit, key in drilled)
    for key, lit in arcs.items():
        m.add_hint(lit, key in used)
    m.add_hint(makespan, max(ms(a[-1]) for a in tl.arrive))
