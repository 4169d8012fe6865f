"""Which boom drills which hole, and in what order: OR-Tools vehicle routing.

**Why OR-Tools routing.** Allocating holes to booms and ordering each boom's holes to minimise the
makespan is a multi-vehicle routing problem with a min-max objective: booms are vehicles that start
and end at their own park, reach is the set of allowed vehicles per node, drilling is service time
and the makespan is the global span of a time dimension. OR-Tools models exactly that, per-vehicle
transit matrices included (each boom has its own move times), and its guided local search finds
near-optimal routes for 150 nodes in a few hundred solutions (seconds); it is well kept, on PyPI, and needs no licence.
CP-SAT, measured (docs/benchmarks.md "Joint CP-SAT model against the routing";
:mod:`pipeline.rig_benchmarks.joint_cpsat`): one model of allocation, order and timing with the standing
conflicts, given the planner's wall time on one core, proves no optimum on the demo face or gen 50
``twin`` (FEASIBLE, 2 % from its own bound), finds routes 2-4 % shorter than the planner's in its own
terms, but the timeline (move conflicts, moves blocked at park) falls those routes back to one boom
at a time (about twice the makespan); the routing stays the planner, the model is a bound and a
measurement.

**The model.** Nodes are the holes some boom can drill (a hole no boom can drill is left out and
reported: OR-Tools reads an empty allowed-vehicle set as "every vehicle"), plus one park node per
boom (start and end of its vehicle). Per boom b the transit from node u to node v is
``drill_s[u] + move_s[b, u, v]`` in integer milliseconds (drilling is the origin's service time),
so the time dimension's cumul at a hole is the instant its drilling starts. The arc cost is the
move time alone (a tie-breaker), the span cost ``span_cost`` per ms of the global span (the latest
return to park less the earliest start, all starts being 0: the makespan).

**Allowed vehicles.** ``RoutingModel.SetAllowedVehiclesForIndex`` of OR-Tools 9.15's Python
wrapper rejects every argument (its ``absl::Span<const int>`` has no SWIG typemap), so a hole's
disallowed booms are removed from its vehicle variable's domain (``VehicleVar(i).RemoveValues``),
the older equivalent form; the routing's local search then never proposes them.

**Precedence across booms.** ``time(i) + drill_s[i] <= time(j)`` is a constraint on two cumuls that
may belong to different vehicles. All vehicles share one clock (every start is fixed at 0), so the
comparison means what it says, but then a boom may have to wait for another: with precedence pairs
the time dimension gets slack (waiting) up to the horizon, and the span counts those waits. Without
them the slack is 0 (a tighter, faster model).

**Conflicts fed back** (:mod:`pipeline.round.planner`): a pair of holes i (boom a) and j (boom b) whose
conflict needed a wait becomes (1) a hard rule: while i is on a and j on b, their drilling
intervals do not overlap (``Max`` of four reified constraints: a vehicle differs, or one interval
ends before the other begins; the time dimension then gets slack, the waits, as with precedence),
and (2) where one boom can drill both, a soft same-vehicle constraint (``AddSoftSameVehicleConstraint``)
costing that wait: on one boom they can never meet.

**A round handed on** (``Instance.start``): a boom that starts elsewhere than at park (where it stood
when the round was interrupted) gets its own start node, that place (no service time, only its
vehicle), and still ends at its park; one that stands at a hole it has not drilled yet (it had moved
there when the round stopped) drills that hole first.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.core.errors import NoRoutes
from pipeline.round.problem import Instance
from pipeline.round.settings import RoundSettings

MS = 1000.0  # time unit of the model: milliseconds


@dataclass(frozen=True)
class Routes:
    routes: list[list[int]]  # per boom, hole indices in drilling order
    left_out: list[int]  # holes no boom can drill
    objective: int
    status: str


def _search_parameters(settings: RoundSettings, time_limit_s: float | None):
    """Guided local search stopped after ``solution_limit`` solutions or ``search_checks`` limit checks
    (:func:`route` counts them: OR-Tools checks its limits at every neighbour it explores, so this bounds
    the work even where no new solution is found, e.g. a route of one hole, where the search would
    otherwise never end): counts, so the same model gives the same routes on any machine (OR-Tools'
    routing search is single-threaded and deterministic).
    A time limit (``time_limit_s`` here, else ``settings.time_limit_s``) is opt-in and stops it
    earlier on a busy machine: not reproducible."""
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    p = pywrapcp.DefaultRoutingSearchParameters()
    p.first_solution_strategy = getattr(routing_enums_pb2.FirstSolutionStrategy, settings.first_solution)
    p.local_search_metaheuristic = routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    p.solution_limit = int(settings.solution_limit)
    limit = time_limit_s if time_limit_s is not None else settings.time_limit_s
    if limit is not None:
        p.time_limit.FromMilliseconds(int(1000 * limit))
    return p


def route(inst: Instance, settings: RoundSettings, same_boom: Mapping[tuple[int, int], float] | None = None,
          apart: Sequence[tuple[int, int, int, int]] = (), initial: Sequence[Sequence[int]] | None = None,
          time_limit_s: float | None = None) -> Routes:
    """Routes of every boom over the holes it may drill (module docstring). ``same_boom``: hole pairs
    ``(i, j)`` -> seconds of penalty when drilled by different booms; ``apart``: ``(i, a, j, b)``, hole
    i on boom a and hole j on boom b are not drilled at the same time; ``initial``: routes to start
    the local search from (dropped when they no longer fit the model)."""
    from ortools.constraint_solver import pywrapcp

    B, H = inst.n_booms, inst.n_holes
    holes = np.flatnonzero(inst.drillable)
    left_out = [int(h) for h in np.flatnonzero(~inst.drillable)]
    n = len(holes)
    if n == 0:
        return Routes([[] for _ in range(B)], left_out, 0, "empty")
    # node -> hole index (H: park); then, handed on, one start node per boom (where it stands)
    handed_on = inst.start is not None
    node_hole = np.concatenate([holes, np.full(B, H), inst.starts if handed_on else np.zeros(0, int)])
    n_nodes = len(node_hole)
    ends = [n + b for b in range(B)]
    starts = [n + B + b for b in range(B)] if handed_on else ends
    manager = pywrapcp.RoutingIndexManager(n_nodes, B, starts, ends)
    model = pywrapcp.RoutingModel(manager)
    drill_ms = np.round(inst.drill_s[holes] * MS).astype(np.int64)
    service = np.concatenate([drill_ms, np.zeros(n_nodes - n, np.int64)])
    transit_cbs = []
    for b in range(B):
        mv = inst.move_s[b][np.ix_(node_hole, node_hole)]
        ok = np.concatenate([inst.reach[b, holes], np.zeros(n_nodes - n, bool)])
        ok[ends[b]] = ok[starts[b]] = True  # only its own park (and start)
        mv = np.where(ok[:, None] & ok[None, :], mv, 0.0)
        mv_ms = np.round(mv * MS).astype(np.int64)
        transit_cbs.append(model.RegisterTransitMatrix((mv_ms + service[:, None]).tolist()))
        model.SetArcCostEvaluatorOfVehicle(model.RegisterTransitMatrix(mv_ms.tolist()), b)
    finite = np.where(np.isfinite(inst.move_s), inst.move_s, 0.0)
    horizon = int(2 * (drill_ms.sum() + B * n * finite.max() * MS) + 1000)
    slack = horizon if inst.precedence or apart else 0
    model.AddDimensionWithVehicleTransits(transit_cbs, slack, horizon, True, "time")
    time = model.GetDimensionOrDie("time")
    time.SetGlobalSpanCostCoefficient(int(settings.span_cost))
    for k, h in enumerate(holes):
        banned = [b for b in range(B) if not inst.reach[b, h]]
        if banned:  # never an empty allowed set here: reach has a boom for every node kept
            model.VehicleVar(manager.NodeToIndex(k)).RemoveValues(banned)
    node_of = {int(h): k for k, h in enumerate(holes)}
    solver = model.solver()
    for b, s in enumerate(inst.starts if handed_on else ()):
        if s < H and s in node_of and inst.reach[b, s]:  # standing at a hole not drilled yet: drill it first
            solver.Add(model.NextVar(model.Start(b)) == manager.NodeToIndex(node_of[s]))
    for i, j in inst.precedence:
        if i in node_of and j in node_of:
            ci, cj = time.CumulVar(manager.NodeToIndex(node_of[i])), time.CumulVar(manager.NodeToIndex(node_of[j]))
            solver.Add(ci + int(drill_ms[node_of[i]]) <= cj)
    for i, a, j, b in apart:
        if i in node_of and j in node_of:
            ii, jj = manager.NodeToIndex(node_of[i]), manager.NodeToIndex(node_of[j])
            ci, cj = time.CumulVar(ii), time.CumulVar(jj)
            either = [(model.VehicleVar(ii) != a).Var(), (model.VehicleVar(jj) != b).Var(),
                      (ci + int(drill_ms[node_of[i]]) <= cj).Var(), (cj + int(drill_ms[node_of[j]]) <= ci).Var()]
            solver.Add(solver.Max(solver.Max(either[0], either[1]), solver.Max(either[2], either[3])) == 1)
    for (i, j), cost in (same_boom or {}).items():
        if i in node_of and j in node_of:
            ids = [manager.NodeToIndex(node_of[i]), manager.NodeToIndex(node_of[j])]
            model.AddSoftSameVehicleConstraint(ids, int(round(cost * MS * max(settings.span_cost, 1))))
    params = _search_parameters(settings, time_limit_s)
    checks = [0]

    def out_of_work() -> bool:  # OR-Tools asks at every neighbour explored: a count of work, reproducible
        checks[0] += 1
        return checks[0] >= settings.search_checks

    model.AddSearchMonitor(solver.CustomLimit(out_of_work))
    solution = None
    if initial is not None:
        model.CloseModelWithParameters(params)
        start = model.ReadAssignmentFromRoutes([[node_of[h] for h in r if h in node_of] for r in initial], True)
        if start is not None:
            solution = model.SolveFromAssignmentWithParameters(start, params)
    if solution is None:
        solution = model.SolveWithParameters(params)
    if solution is None:
        raise RoutingFailed(f"round: OR-Tools found no routes ({_status(model)}) for {n} holes and {B} booms; "
                            "check round.precedence against the reach table")
    routes = []
    for b in range(B):
        r, idx = [], model.Start(b)
        while not model.IsEnd(idx):
            node = manager.IndexToNode(idx)
            if node < n:
                r.append(int(holes[node]))
            idx = solution.Value(model.NextVar(idx))
        routes.append(r)
    return Routes(routes, left_out, int(solution.ObjectiveValue()), _status(model))


class RoutingFailed(NoRoutes):
    """OR-Tools found no routes: for the first solve, the round cannot be planned (exit 3; the message points
    at round.precedence against the reach table); for a re-optimisation with conflicts fed back, the planner
    keeps its best round."""


def _status(model) -> str:
    # OR-Tools 9.15's RoutingSearchStatus (a solution or time limit hit before a local optimum: "partial")
    names = {0: "not solved", 1: "success", 2: "partial (local optimum not reached)", 3: "fail",
             4: "fail (time limit)", 5: "invalid", 6: "infeasible", 7: "optimal"}
    return names.get(int(model.status()), str(model.status()))
