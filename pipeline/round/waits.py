"""Exact waits for fixed routes: a disjunctive schedule solved by CP-SAT, conflicts added lazily.

Given each boom's route, what is left to decide is when each move starts (a boom waits by standing
at its previous node). Every boom's timeline is a chain of *segments*: the standing at its start
node until its first move, then per hole a move and the standing there (drilling, then maybe
waiting), then the move home and the standing at park, which never ends. Two segments of two booms
whose configurations conflict must not overlap in time: one ends before the other starts (a
disjunction, one literal). The makespan is minimised over all move starts.

**Which pairs.** Standing x standing conflicts depend on nothing but the two nodes: every such pair
goes in up front (one batch through the oracle). A pair with a move is timing-dependent, so it is
added lazily: solve, time the answer (:func:`pipeline.round.timeline.simulate`), list every pair of
segments the oracle finds in conflict (:func:`pipeline.round.timeline.conflicting_segments`), add them
as disjunctions, solve again, until the timeline is conflict-free. A move x standing pair is exact
(the standing boom does not move, so the move meets it at any relative timing); a move x move pair is
conservative (the two moves are kept apart entirely, though another relative timing might be clear).
So the answer is **optimal for the routes under this disjunctive model**: CP-SAT's status says
whether it proved it (``optimal``) or stopped at its deterministic limit with a bound (``feasible``:
the gap is reported), or that no waits part the routes (``infeasible``: a deadlock, such as one
boom's standing place in another's every path home).

**Integer times.** CP-SAT works in integer milliseconds. A move lasts ``ceil`` of its milliseconds
when it is an obstacle and the standing after it starts at ``floor``: both conservative, so a
disjunction the model keeps also holds in the exact (float) timeline, which is built from the
model's move starts by :func:`simulate`. Drilling lasts its ``ceil`` too.

**Left-shift.** CP-SAT's optimum may place a wait later than needed (the makespan does not see it).
With the order of every disjunction fixed as the solver chose it, the earliest start of every move
is the least solution of a system of difference constraints, found by Bellman-Ford (vectorised):
no start later than the solver's, the same makespan, and each wait tight against the segment it
waits for (the wait's record names it, for the routing's feedback).

**Reproducible.** One worker, a fixed seed, limited by deterministic time
(``round.waits_deterministic_s``), not by the clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from ortools.sat.python import cp_model

from pipeline.round.problem import Instance
from pipeline.round.settings import RoundSettings
from pipeline.round.timeline import Segment, Timeline, conflicting_segments, resolve, simulate

GAP_S = 1e-6  # kept between two segments a disjunction orders: touching ends stay apart in float arithmetic
STATUS = {cp_model.OPTIMAL: "optimal", cp_model.FEASIBLE: "feasible", cp_model.INFEASIBLE: "infeasible",
          cp_model.MODEL_INVALID: "invalid", cp_model.UNKNOWN: "unknown"}


class _Chain:
    """One boom's segments as expressions of its move starts ``S[0..n]``: in integer milliseconds for
    the model (conservative: ``ceil`` and ``floor``), or exact in seconds for the left-shift."""

    def __init__(self, model: cp_model.CpModel, inst: Instance, b: int, route: list[int], horizon: int):
        H = inst.n_holes
        self.nodes = [inst.starts[b], *route, H]
        n = len(route)
        self.mv_s = np.array([inst.move_s[b, u, v] for u, v in zip(self.nodes[:-1], self.nodes[1:], strict=True)])
        self.drill_s = inst.drill_s[route] if n else np.zeros(0)
        self.dc = np.ceil(self.mv_s * 1000).astype(np.int64)  # as an obstacle (covers the exact move)
        self.df = np.floor(self.mv_s * 1000).astype(np.int64)  # the standing after it starts no later
        self.drill = np.ceil(self.drill_s * 1000).astype(np.int64)
        self.S = [model.NewIntVar(0, horizon, f"s{b}_{k}") for k in range(n + 1)]
        self.b, self.n, self.horizon = b, n, horizon
        for k in range(n):  # the chain: move, drilling, next move
            model.Add(self.S[k + 1] >= self.S[k] + int(self.dc[k] + self.drill[k]))

    def node(self, seg: Segment) -> int:
        """Where the boom stands (a standing) or where its move ends."""
        return self.nodes[seg.k + 1]

    def start(self, seg: Segment, exact: bool = False):
        """(var index or None, offset): the segment's start is ``S[var] + offset`` (None: the constant)."""
        if seg.move:
            return seg.k, 0
        if seg.k < 0:
            return None, 0
        return seg.k, float(self.mv_s[seg.k]) if exact else int(self.df[seg.k])

    def end(self, seg: Segment, exact: bool = False):
        """(var index or None, offset); None with offset ``horizon`` (exact: inf): the final standing,
        which never ends."""
        if seg.move:
            return seg.k, float(self.mv_s[seg.k]) if exact else int(self.dc[seg.k])
        if seg.k >= self.n:
            return None, math.inf if exact else self.horizon
        return seg.k + 1, 0

    def ready(self, k: int, exact: bool = False):
        """Move k + 1 may start this long after move k: the move and the drilling of its hole."""
        return float(self.mv_s[k] + self.drill_s[k]) if exact else int(self.dc[k] + self.drill[k])

    def standings(self) -> list[Segment]:
        return [Segment(self.b, False, k) for k in range(-1, self.n + 1)]


def _expr(chain: _Chain, point):
    var, off = point
    return off if var is None else chain.S[var] + off


def _standing_pairs(chains: list[_Chain], oracle) -> list[tuple[Segment, Segment]]:
    """Every pair of standings of two booms whose nodes conflict (one batch per boom pair)."""
    out = []
    for a in range(len(chains)):
        for b in range(a + 1, len(chains)):
            sa, sb = chains[a].standings(), chains[b].standings()
            ia, ib = np.meshgrid(np.arange(len(sa)), np.arange(len(sb)), indexing="ij")
            ia, ib = ia.ravel(), ib.ravel()
            na = np.array([chains[a].node(s) for s in sa])[ia]
            nb = np.array([chains[b].node(s) for s in sb])[ib]
            one = np.ones(len(ia))
            first, _ = oracle.check(a, _standing_at(na, one), b, _standing_at(nb, one), 0 * one, one)
            out += [(sa[i], sb[j]) for i, j in zip(ia[np.isfinite(first)], ib[np.isfinite(first)], strict=True)]
    return out


def _standing_at(nodes: np.ndarray, one: np.ndarray) -> dict:
    """Segments standing at ``nodes`` over [0, 1] (the oracle's batch form)."""
    return {"t0": 0 * one, "t1": one, "u": nodes, "v": nodes, "k": 0 * nodes, "p": nodes}


@dataclass
class WaitsResult:
    timeline: Timeline
    status: str  # optimal | feasible | infeasible | unknown (the last solve's)
    objective_s: float
    bound_s: float  # CP-SAT's proven lower bound of the makespan for these routes (the model's)
    rounds: int  # solves (the lazy loop)
    pairs: int  # conflicting segment pairs found over all solves (the last model holds those found before it)
    conflicts_left: int  # segment pairs in conflict in the final timeline (0 unless the loop gave up)


def exact_waits(inst: Instance, routes: list[list[int]], oracle, deterministic_s: float = 5.0,
                max_rounds: int = 30, seed: int = 0) -> WaitsResult:
    """The routes' timeline with optimal waits (module docstring). ``timeline.repairs`` lists each wait
    with the segment it waits for; the result's status is the certificate."""
    routes = [list(r) for r in routes]
    free = simulate(inst, routes)  # no waits: the hint of the first solve, and a scale for the horizon
    horizon = int(math.ceil(sum(float(a[-1]) for a in free.arrive) * 1000)) * 2 + 1000
    pairs: set[tuple[Segment, Segment]] = set()
    hint = None
    status, obj, bound, rounds, tl, left, least = "unknown", math.nan, math.nan, 0, free, -1, math.inf
    standing = None
    while rounds < max_rounds:
        model = cp_model.CpModel()
        chains = [_Chain(model, inst, b, r, horizon) for b, r in enumerate(routes)]
        if standing is None:
            standing = _standing_pairs(chains, oracle)
            pairs.update(standing)
        lits = _disjunctions(model, chains, sorted(pairs, key=_key))
        _precedence(model, inst, chains, routes)
        span = model.NewIntVar(0, horizon, "makespan")
        model.AddMaxEquality(span, [c.S[c.n] + int(c.dc[c.n]) for c in chains])
        model.Minimize(span)
        for c in chains:
            start = hint[c.b] if hint is not None else free.move_start[c.b]
            for var, v in zip(c.S, start, strict=True):
                model.AddHint(var, int(math.ceil(v * 1000)))
        solver = cp_model.CpSolver()
        solver.parameters.num_workers = 1
        solver.parameters.catch_sigint_signal = False  # Ctrl-C reaches the stage (CP-SAT would eat it, then exit 130)
        solver.parameters.random_seed = int(seed)
        solver.parameters.max_deterministic_time = float(deterministic_s)
        code = solver.Solve(model)
        rounds += 1
        status = STATUS.get(code, "unknown")
        if code not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            break
        obj, bound = solver.ObjectiveValue() / 1000, solver.BestObjectiveBound() / 1000
        starts, shifted = _left_shift(chains, solver, lits, inst, routes)
        hint = starts
        tl = simulate(inst, routes, starts)
        found, least = conflicting_segments(tl, oracle)
        new = {p for p in found if p not in pairs}
        left = len(found)
        if not found or not new:
            break
        pairs |= new
    if status in ("optimal", "feasible"):
        tl.repairs = _waits(chains, shifted)
        tl.conflicts_left, tl.min_clearance = left, least
        tl.waits = {"method": "exact", "status": status, "objective_s": obj, "bound_s": bound,
                    "rounds": rounds, "pairs": len(pairs)}
    return WaitsResult(tl, status, obj, bound, rounds, len(pairs), left)


def _key(p: tuple[Segment, Segment]):
    a, b = p
    return (a.boom, a.move, a.k, b.boom, b.move, b.k)


def _disjunctions(model, chains, pairs):
    """Per pair (p, q): a literal ``x``, x -> p ends before q starts, not x -> q before p; a pair with the
    final standing (which never ends) has one order only. Returns [(p, q, lit or None, p_first)]."""
    out = []
    for p, q in pairs:
        cp, cq = chains[p.boom], chains[q.boom]
        ep, eq = cp.end(p), cq.end(q)
        sp, sq = cp.start(p), cq.start(q)
        p_never, q_never = ep[0] is None and ep[1] == cp.horizon, eq[0] is None and eq[1] == cq.horizon
        if p_never and q_never:  # both stand for good: no order parts them
            model.Add(0 == 1)
            out.append((p, q, None, True))
            continue
        if p_never:  # q must end before p starts
            model.Add(_expr(cq, eq) <= _expr(cp, sp))
            out.append((p, q, None, False))
            continue
        if q_never:
            model.Add(_expr(cp, ep) <= _expr(cq, sq))
            out.append((p, q, None, True))
            continue
        x = model.NewBoolVar("")
        model.Add(_expr(cp, ep) <= _expr(cq, sq)).OnlyEnforceIf(x)
        model.Add(_expr(cq, eq) <= _expr(cp, sp)).OnlyEnforceIf(x.Not())
        out.append((p, q, x, None))
    return out


def _precedence_positions(inst: Instance, routes: list[list[int]]):
    """Per precedence pair (i before j) on the routes: (boom of i, its position, boom of j, its position)."""
    where = {h: (b, k) for b, r in enumerate(routes) for k, h in enumerate(r)}
    return [(*where[i], *where[j]) for i, j in inst.precedence if i in where and j in where]


def _precedence(model, inst: Instance, chains: list[_Chain], routes: list[list[int]]):
    """Hole i finished before hole j's drilling starts: j's arrival (floor) after i's end (ceil)."""
    for a, ki, b, kj in _precedence_positions(inst, routes):
        ca, cb = chains[a], chains[b]
        model.Add(cb.S[kj] + int(cb.df[kj]) >= ca.S[ki] + ca.ready(ki))


def _edges(chains, lits, solver, inst: Instance, routes):
    """The difference constraints ``x[dst] >= x[src] + w`` (seconds, exact durations) of the schedule
    with every disjunction ordered as the solver chose (flat var indices; the last, -1, is the
    constant 0), with the disjunction each came from (None: a chain or a precedence)."""
    base = np.cumsum([0] + [c.n + 1 for c in chains])
    src, dst, w, why = [], [], [], []

    def add(ca, pa, cb, pb, tag):  # end point pa of chain ca <= start point pb of chain cb
        (va, oa), (vb, ob) = pa, pb
        if vb is None or math.isinf(oa):
            return  # an upper bound (holds for any earlier schedule) or nothing
        src.append(-1 if va is None else base[ca.b] + va)
        dst.append(base[cb.b] + vb)
        w.append(oa - ob)
        why.append(tag)

    for c in chains:
        for k in range(c.n):
            add(c, (k, c.ready(k, True)), c, (k + 1, 0.0), None)
    for a, ki, b, kj in _precedence_positions(inst, routes):
        ca, cb = chains[a], chains[b]
        add(ca, (ki, ca.ready(ki, True)), cb, (kj, float(cb.mv_s[kj])), None)
    for p, q, x, p_first in lits:
        first = bool(solver.Value(x)) if x is not None else p_first
        (e, f) = (p, q) if first else (q, p)
        ce, cf = chains[e.boom], chains[f.boom]
        (ve, oe) = ce.end(e, True)
        add(ce, (ve, oe + GAP_S), cf, cf.start(f, True), (e, f))
    return base, np.array(src, np.int64), np.array(dst, np.int64), np.array(w, float), why


def _left_shift(chains, solver, lits, inst, routes):
    """The earliest move starts (s, per boom) with every disjunction's order as the solver chose it,
    and the constraint system they solve (for the wait records)."""
    base, src, dst, w, why = _edges(chains, lits, solver, inst, routes)
    n = int(base[-1])
    x = np.zeros(n + 1)  # the last entry is the constant 0 (index -1)
    for _ in range(n + 2):  # Bellman-Ford, all edges at once: at most n passes (no positive cycle)
        new = x.copy()
        np.maximum.at(new, dst, x[src] + w)
        new[-1] = 0.0
        if np.array_equal(new, x):
            break
        x = new
    solved = np.array([solver.Value(v) for c in chains for v in c.S]) / 1000
    if np.any(x[:-1] > solved + 1e-3):  # cannot happen: the solver's schedule satisfies every edge (up to the GAPs)
        raise RuntimeError("waits: the left-shifted schedule is later than the solver's")
    return [x[base[b]:base[b + 1]] for b in range(len(chains))], (base, src, dst, w, why, x)


def _waits(chains, shifted) -> list[dict]:
    """One record per move that waits: the segment it waits for (a tight disjunction edge), in the
    form of the greedy repair's records (``boom``, ``move``, ``until``, ``wait_s``, ``nodes``, ``booms``)."""
    base, src, dst, w, why, x = shifted
    out = []
    for c in chains:
        for k in range(c.n + 1):
            v = base[c.b] + k
            ready = 0.0 if k == 0 else x[v - 1] + c.ready(k - 1, True)
            if x[v] <= ready + 1e-9:
                continue
            tight = [e for e in np.flatnonzero((dst == v) & (x[src] + w >= x[v] - 1e-9)) if why[e] is not None]
            if not tight:
                continue
            first, then = why[tight[0]]
            ce, cf = chains[first.boom], chains[then.boom]
            out.append({"boom": c.b, "move": k, "t": float(x[v]), "until": float(x[v]),
                        "wait_s": float(x[v] - ready),
                        "kind": "moving" if first.move or then.move else "standing",
                        "nodes": (int(cf.node(then)), int(ce.node(first))), "booms": (then.boom, first.boom)})
    return out


def place_waits(inst: Instance, routes: list[list[int]], oracle, settings: RoundSettings) -> Timeline:
    """The routes' timeline with waits placed as ``round.waits`` says: ``exact`` (CP-SAT; the greedy
    repair where it proves no schedule or leaves a conflict), ``greedy`` (the repair rule of
    :mod:`pipeline.round.timeline`), ``best`` (both, the better kept). ``timeline.waits`` says which."""
    if settings.waits != "greedy":
        ex = exact_waits(inst, routes, oracle, settings.waits_deterministic_s, settings.waits_rounds,
                         settings.waits_seed)
        ok = ex.status in ("optimal", "feasible") and ex.conflicts_left == 0
        if ok and settings.waits == "exact":
            return ex.timeline
    tl = resolve(inst, routes, oracle, settings.max_repairs, escalations=settings.escalations)
    tl.waits = {"method": "greedy"}
    if settings.waits == "greedy":
        return tl
    if not ok:
        tl.waits["exact"] = {"status": ex.status, "rounds": ex.rounds, "conflicts_left": ex.conflicts_left}
        return tl
    better = (ex.timeline.conflicts_left, ex.timeline.makespan) <= (tl.conflicts_left, tl.makespan)
    if better:
        ex.timeline.waits["greedy_s"] = tl.makespan
        return ex.timeline
    tl.waits["exact_s"] = ex.timeline.makespan
    return tl
