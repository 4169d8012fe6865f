"""Zones the planner chooses (docs/round.md, "Zones the planner chooses"): where an interlock makes a boom
stand, let either boom go first.

A boom stands when an interlock holds its action ``v`` until another boom's action ``u`` has ended and
that boom is late. A zone with a section of each boom around ``u`` and ``v`` takes away the interlocks
between the two sections: whichever boom arrives first goes through its section, the other waits
outside. Its neighbours' orders stay (every other conflicting pair keeps its interlock), so the sections
must be wide enough that the waiting does not move one action on: the search tries sections reaching
``reach`` actions before and after ``u`` and ``v``.

**Search**, greedy over the round's interlocks, the one that makes booms stand longest first (mean wait
over the search draws): for each, a coordinate descent over the four reaches, every candidate executed
under the rule by events on the first ``search_draws`` random draws. A candidate is kept only if

- no draw deadlocks, and neither the nominal makespan (model durations) nor the p95 of the draws'
  makespans grows by more than ``makespan_slack``;
- the p95 of the standing share drops by at least ``min_gain`` (the issue's figure: the time booms wait
  before their actions, summed over booms, over the makespan);
- its proof holds (:mod:`pipeline.events.zone_proof`): no interleaving deadlocks, and every pair of
  segments that may now overlap is clear, the stands before zones included. Candidates that fail it are
  passed over for the next best.

Sections of one boom never overlap (a boom is inside one zone at a time), and an interlock that comes
from the plan's precedence (hole i before hole j) is never taken away.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.core.settings import rule
from pipeline.events.actions import Actions
from pipeline.events.graph import reduce_edges
from pipeline.events.rule import execute
from pipeline.events.zone_proof import MAX_STATES, closure, deadlock, unsafe
from pipeline.events.zones import NO_ZONES, Zones


@dataclass(frozen=True)
class ZoneSettings:
    """``conf/zones/default.yaml`` (module docstring)."""

    choose: bool = True
    search_draws: int = field(default=300, metadata=rule(ge=1, le=10_000))
    reach: list[int] = field(default_factory=lambda: [0, 2, 4, 6], metadata=rule(ge=0, le=50, min_items=1,
                                                                                  max_items=10))
    makespan_slack: float = field(default=0.005, metadata=rule(ge=0, le=1))
    min_gain: float = field(default=0.001, metadata=rule(ge=0, le=1))
    proofs_per_interlock: int = field(default=5, metadata=rule(ge=1, le=100))
    passes: int = field(default=2, metadata=rule(ge=1, le=10))
    descents: int = field(default=1, metadata=rule(ge=1, le=10))
    max_states: int = field(default=MAX_STATES, metadata=rule(ge=1, le=1_000_000_000))


@dataclass
class Choice:
    """The zones kept, the graph's edges with their interlocks taken away, and what the search did."""

    zones: Zones
    edges: np.ndarray
    stats: dict = field(default_factory=dict)


def _standing_p95(acts: Actions, edges: np.ndarray, dur_s: np.ndarray, zones: Zones):
    """The p95 over the draws of the standing share (summed over booms, over each draw's makespan), and
    the draws' execution."""
    ex = execute(acts, edges, dur_s, zones)
    span = np.where(ex.makespan > 0, ex.makespan, 1.0)
    with np.errstate(invalid="ignore", over="ignore"):  # a deadlocked draw (inf), refused by the caller
        return float(np.percentile(ex.standing.sum(1) / span, 95)), ex


def zones_of(sections: list[tuple[int, int, int, int]]) -> Zones:
    """Two-boom zones ``Z1, Z2, ...`` from sections ``(a_first, a_last, b_first, b_last)``."""
    if not sections:
        return NO_ZONES
    names = tuple(n for i in range(len(sections)) for n in (f"Z{i + 1}",) * 2)
    return Zones(names, np.array([x for s in sections for x in (s[0], s[2])], int),
                 np.array([x for s in sections for x in (s[1], s[3])], int))


def choose_zones(acts: Actions, edges: np.ndarray, fixed: np.ndarray, conflict: np.ndarray, drill_s: np.ndarray,
                 factors: np.ndarray, settings: ZoneSettings) -> Choice:
    """Zones for the robust round (module docstring). ``edges``: every ordered pair (before reduction),
    ``fixed``: those that must stay (the plan's precedence), ``conflict``: ``(K, K)`` the actions'
    sweeps conflict, ``drill_s`` the model drilling times, ``factors`` ``(D, H)`` the search draws."""
    started = time.perf_counter()
    K, B = len(acts), len(acts.booms)
    edges = np.unique(np.asarray(edges, int).reshape(-1, 2), axis=0)
    stats = {"zones": 0, "candidates": 0, "proofs_failed": 0, "proof_problems": []}
    if not settings.choose or B < 2 or K == 0 or len(edges) == 0:
        return Choice(NO_ZONES, edges, {**stats, "search_s": time.perf_counter() - started})
    dur = factors * np.asarray(drill_s, float)[None, :]
    nominal = lambda e, z: float(execute(acts, e, drill_s, z).makespan[0])  # noqa: E731
    current, ex = _standing_p95(acts, edges, dur, NO_ZONES)
    span0 = (nominal(edges, NO_ZONES), float(np.percentile(ex.makespan, 95)))  # nominal, and p95 of the draws
    stats["standing_p95_before"] = current
    fixed_set = {tuple(map(int, x)) for x in np.asarray(fixed, int).reshape(-1, 2)}
    bounds = np.searchsorted(acts.boom, np.arange(B + 1))
    prev = acts.previous
    seq = acts.sequence_edges()
    sections: list[tuple[int, int, int, int]] = []
    removed = np.zeros(len(edges), bool)
    for _ in range(settings.passes):  # the standing a zone takes away may reappear at another interlock
        added = False
        wait = ex.start - np.where(prev >= 0, ex.end[:, np.maximum(prev, 0)], 0.0)
        held = reduce_edges(K, seq, edges[~removed])
        held = held[acts.boom[held[:, 0]] != acts.boom[held[:, 1]]]
        cost = wait.mean(0)[held[:, 1]]
        order = np.argsort(-cost, kind="stable")
        for u, v in held[order][cost[order] > 0]:
            found = _search(acts, edges, removed, sections, int(u), int(v), bounds, fixed_set, dur, drill_s, span0,
                            settings, nominal, current, conflict, stats)
            if found is not None:
                s, inner, current, ex = found
                sections.append(s)
                removed |= inner
                added = True
        if not added:
            break
    stats.update(zones=len(sections), standing_p95_after=current, search_s=time.perf_counter() - started)
    return Choice(zones_of(sections), edges[~removed], stats)


def _search(acts, edges, removed, sections, u, v, bounds, fixed_set, dur, drill_s, span0, settings, nominal,
            current, conflict, stats):
    """The best proved zone around interlock ``u -> v`` (module docstring): ``(section pair, inner edges,
    standing p95, its execution)``, or None when none cuts the standing by ``min_gain``."""
    a, b = int(acts.boom[u]), int(acts.boom[v])

    def section(c):
        return (max(u - c[0], bounds[a]), min(u + c[1], bounds[a + 1] - 1),
                max(v - c[2], bounds[b]), min(v + c[3], bounds[b + 1] - 1))

    tried: dict = {}
    cfg = [0, 0, 0, 0]
    for _ in range(settings.descents):
        for ci in range(4):  # coordinate descent over the four reaches
            for r in settings.reach:
                c = list(cfg)
                c[ci] = int(r)
                s = section(c)
                if s not in tried:
                    tried[s] = _candidate(acts, edges, removed, sections, s, fixed_set, dur, drill_s, span0,
                                          settings, nominal)
                    stats["candidates"] += 1
            good = [(t[0], k) for k, t in tried.items() if t is not None]
            if good:
                best = min(good)[1]
                cfg = [u - best[0], best[1] - u, v - best[2], best[3] - v]
    ranked = sorted((t[0], k) for k, t in tried.items() if t is not None and t[0] < current - settings.min_gain)
    for obj, s in ranked[:settings.proofs_per_interlock]:
        inner = tried[s][1]
        trial = zones_of(sections + [s])
        problem = prove(acts, edges[~(removed | inner)], trial, conflict, settings.max_states)
        if problem is None:
            return s, inner, obj, tried[s][2]
        stats["proofs_failed"] += 1
        stats["proof_problems"].append(problem)
    return None


def _candidate(acts, edges, removed, sections, s, fixed_set, dur, drill_s, span0, settings, nominal):
    """``(standing p95, inner edges, execution)`` of the round with section pair ``s`` added, or None
    when it is not allowed (overlaps a section, takes away a precedence, deadlocks a draw, lengthens the
    nominal makespan or the draws' p95 beyond the slack)."""
    a1, a2, b1, b2 = s
    for o in sections:
        for p1, p2 in ((a1, a2), (b1, b2)):
            for q1, q2 in ((o[0], o[1]), (o[2], o[3])):
                if acts.boom[p1] == acts.boom[q1] and not (p2 < q1 or q2 < p1):
                    return None
    x, y = edges[:, 0], edges[:, 1]
    inner = (((x >= a1) & (x <= a2) & (y >= b1) & (y <= b2)) | ((x >= b1) & (x <= b2) & (y >= a1) & (y <= a2)))
    inner &= ~removed
    if not inner.any() or any(tuple(map(int, e)) in fixed_set for e in edges[inner]):
        return None
    e = edges[~(removed | inner)]
    z = zones_of(sections + [s])
    obj, ex = _standing_p95(acts, e, dur, z)
    if (ex.deadlocked.any() or nominal(e, z) > span0[0] * (1.0 + settings.makespan_slack)
            or np.percentile(ex.makespan, 95) > span0[1] * (1.0 + settings.makespan_slack)):
        return None
    return obj, inner, ex


def prove(acts: Actions, edges: np.ndarray, zones: Zones, conflict: np.ndarray, max_states: int = MAX_STATES
          ) -> str | None:
    """None when the round with ``edges`` and ``zones`` is proved robust (:mod:`pipeline.events.zone_proof`),
    else why not."""
    try:
        stuck = deadlock(acts, edges, zones, max_states)
    except ValueError as err:
        return f"no proof of deadlock freedom: {err}"
    if stuck is not None:
        return "an interleaving deadlocks with the booms before " + ", ".join(
            acts.name(k) for k in stuck if k >= 0)
    return unsafe(acts, conflict, closure(acts, edges), zones)
