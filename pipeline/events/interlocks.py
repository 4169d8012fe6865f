"""Interlocks that make a planned round robust (docs/reference.md, section 8): an action dependency graph.

**Construction.**

1. The plan's actions (:func:`pipeline.events.actions.actions_of`) and every pair of actions of two
   booms that *conflict* (:mod:`pipeline.events.conflicts`: their sweeps come within d_boom plus the
   oracle's margin at some relative timing; certified).
2. Every conflicting pair is ordered, earlier first by the key ``(t_start, t_end, boom, action)`` of
   the plan: a pair that does not overlap in the plan keeps its planned order; one that overlaps
   (both running at once, clear only at the planned relative timing) is *serialised*: the one that
   starts later waits for the other to end. Precedence pairs of the instance (hole i before hole j)
   become interlocks drill i -> drill j. Sequence edges (each boom's order) also follow the key, so
   the graph is acyclic: no deadlock for any durations.
3. The round is re-timed under the execution rule with the nominal durations. Its conflicting pairs
   are all ordered, so none overlaps; re-ordering by the new timeline gives the same edges (the loop
   of "serialise, re-time" is at its fixed point after one pass).
4. The re-timed nominal timeline is checked with :func:`pipeline.round.timeline.scan` (the oracle).
   What can still break is a boom *standing* between two actions: serialising can make a boom wait
   at a place where, in the plan, it never stood while the other action ran. Then the order forces
   ``a_i < b_j < a_{i+1}`` (A stands at end(a_i) = start(a_{i+1}) during b_j), and the fix is to flip
   one of the two orders: A goes on first (``a_{i+1} < b_j``) or B goes first (``b_j < a_i``);
   likewise for two standing booms. Of the flips that keep the graph acyclic the one with the shorter
   nominal makespan is taken, each pair is flipped at most once, and the scan is repeated: the loop
   ends after at most one flip per conflicting pair. When no flip is possible the pair is reported
   (``RobustRound.problem``), never hidden.
5. Interlocks implied by others and the sequences are dropped (transitive reduction of the DAG,
   :func:`pipeline.events.graph.reduce_edges`: a reachability matrix, cheap for hundreds of
   actions); the execution is the same with or without them.
6. With ``zone_search``, zones where an interlock makes a boom stand (:mod:`pipeline.events.zone_choice`,
   proved by :mod:`pipeline.events.zone_proof` against the graph of step 2 and the nominal round of
   step 4): their interlocks are taken away, the rest reduced again, and the nominal round re-timed under
   the rule with the zones and scanned once more (were it not clear, the zones would be dropped, said in
   ``stats["zones_dropped"]``).

**Why any execution is then clear** (the robustness argument). Let T be the re-timed nominal
timeline, clear at every instant by the scan (standing included), and let every conflicting pair be
ordered consistently with T. Take any execution under the rule and any instant. Each boom is either
in an action or standing between two (at end(a_i) = start(a_{i+1}), which belongs to both sweeps;
before its first action at park = start(a_0), after its last at park = end(a_last)).

- Two booms in actions a_i, b_j at once: an ordered pair never overlaps (the later starts after the
  earlier has ended), so they are not a conflicting pair, and every pair of their configurations is
  clear by the certified sweep test.
- A standing at c between a_i and a_{i+1} while B is in b_j (or stands): if b_j does not conflict
  with a_i or a_{i+1} then c, which lies in both sweeps, is clear of b_j. Otherwise b_j is ordered
  against both, and it can overlap the standing only as a_i < b_j < a_{i+1}; that order holds in T
  too, where A therefore stood at c throughout b_j: the same configurations side by side (A does not
  move), which the scan found clear. Two standing booms: the same with the four neighbour actions.

Self and tunnel clearances do not depend on timing (each move's motion is the planned one). Every
hole is drilled once (each drill is one action). With the nominal durations the execute stage reproduces
T exactly (T is that execution).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.events.actions import Actions, actions_of
from pipeline.events.conflicts import Conflicts, conflicts
from pipeline.events.draws import DrawSettings, draws
from pipeline.events.graph import find_cycle, reduce_edges
from pipeline.events.rule import Execution, execute, realised
from pipeline.events.zone_choice import ZoneSettings, choose_zones
from pipeline.events.zones import NO_ZONES, Zones
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline, scan


@dataclass
class RobustRound:
    """The actions (with the re-timed nominal times), the reduced interlocks ``(before, after)``, the
    re-timed nominal timeline, the conflicts, and what it took. ``problem``: why the round could not
    be made robust (a pair of actions named), None when it is."""

    actions: Actions
    interlocks: np.ndarray
    timeline: Timeline
    conflicts: Conflicts
    stats: dict = field(default_factory=dict)
    problem: str | None = None
    zones: Zones = NO_ZONES  # where either boom may go first (step 6); none: every conflicting pair is ordered


def _rank(acts: Actions) -> np.ndarray:
    order = np.lexsort((acts.index, acts.boom, acts.t_end, acts.t_start))
    rank = np.empty(len(acts), int)
    rank[order] = np.arange(len(acts))
    return rank


def precedence_edges(inst: Instance, acts: Actions) -> np.ndarray:
    """Drill i -> drill j for each precedence pair (i, j) drilled by two different booms."""
    drill_of = {int(h): k for k, h in zip(np.flatnonzero(acts.is_drill), acts.hole[acts.is_drill], strict=True)}
    out = [(drill_of[i], drill_of[j]) for i, j in inst.precedence
           if i in drill_of and j in drill_of and acts.boom[drill_of[i]] != acts.boom[drill_of[j]]]
    return np.asarray(out, int).reshape(-1, 2)


def _state(acts: Actions, ex: Execution, seg: dict, b: int, t: float):
    """Boom b at the scan's segment ``seg`` at instant t: ``("in", k)`` or ``("stand", prev, next)``."""
    mine = np.flatnonzero(acts.boom == b)
    moves = mine[~acts.is_drill[mine]]
    k = int(seg["k"])
    if seg["u"] != seg["v"]:
        return ("in", int(moves[k]))
    if k < 0:
        return ("stand", -1, int(mine[0]))
    mv = int(moves[k])
    nxt = mv + 1 if mv + 1 <= mine[-1] else -1
    if nxt >= 0 and acts.is_drill[nxt]:  # at a hole: maybe standing (an interlock), its drill, then a pause
        if t < ex.start[0, nxt] - 1e-9:
            return ("stand", mv, nxt)
        if t < ex.end[0, nxt] - 1e-9:
            return ("in", nxt)
        return ("stand", nxt, nxt + 1 if nxt + 1 <= mine[-1] else -1)
    return ("stand", mv, nxt)


def _flips(sa, sb) -> list[tuple[int, int]]:
    """Orders (u before v) that end the co-occurrence of states sa and sb (module docstring, step 4)."""
    out = []
    for s, o in ((sa, sb), (sb, sa)):
        if s[0] != "stand":
            continue
        prev, nxt = s[1], s[2]
        o_first = o[1]  # the other's action running, or the one that brought it where it stands
        o_last = o[1] if o[0] == "in" else o[2]  # the other's action running, or the one it leaves by
        if nxt >= 0 and o_first >= 0:
            out.append((nxt, o_first))  # the standing boom goes on first
        if prev >= 0 and o_last >= 0:
            out.append((o_last, prev))  # the other is done before the boom gets there
    return out


def _orient(edges: set, u: int, v: int) -> set:
    return (edges - {(v, u)}) | {(u, v)}


def robust_round(inst: Instance, tl: Timeline, oracle, max_flips: int | None = None,
                 zone_search: tuple[ZoneSettings, DrawSettings] | None = None) -> RobustRound:
    """Interlocks for the planned timeline ``tl`` (module docstring); with ``zone_search`` (the zones'
    settings and the draws' whose first random draws the search runs on), zones where they cut the
    standing (step 6, :mod:`pipeline.events.zone_choice`)."""
    started = time.perf_counter()
    acts = actions_of(inst, tl)
    conf = conflicts(acts, oracle)
    swept = time.perf_counter() - started
    pairs = conf.conflicting
    rank = _rank(acts)
    first = rank[pairs[:, 0]] < rank[pairs[:, 1]]
    ordered = np.where(first[:, None], pairs, pairs[:, ::-1])
    overlap = (np.minimum(acts.t_end[pairs[:, 0]], acts.t_end[pairs[:, 1]])
               - np.maximum(acts.t_start[pairs[:, 0]], acts.t_start[pairs[:, 1]])) > 1e-9
    edges = {(int(u), int(v)) for u, v in ordered} | {(int(u), int(v)) for u, v in precedence_edges(inst, acts)}
    conflicting = {frozenset((int(u), int(v))) for u, v in pairs}
    seq = acts.sequence_edges()
    flipped: set = set()
    problem = None
    limit = len(pairs) if max_flips is None else max_flips
    while True:
        ex = execute(acts, np.array(sorted(edges), int).reshape(-1, 2), inst.drill_s)
        if ex.deadlock is not None:  # cannot happen (every edge follows the key); said, not hidden
            problem = "the interlocks deadlock: " + " -> ".join(acts.name(k) for k in ex.deadlock)
            break
        _, nominal = realised(inst, acts, ex)
        c = scan(nominal, oracle)
        if c is None:
            break
        sa = _state(acts, ex, c["seg_a"], c["a"], c["t"])
        sb = _state(acts, ex, c["seg_b"], c["b"], c["t"])
        what = f"{_say(acts, sa)} and {_say(acts, sb)} at t = {c['t']:.2f} s"
        options = [(u, v) for u, v in _flips(sa, sb) if frozenset((u, v)) in conflicting
                   and frozenset((u, v)) not in flipped]
        best = None
        for u, v in options:
            trial = _orient(edges, u, v)
            e = np.array(sorted(trial), int).reshape(-1, 2)
            if find_cycle(len(acts), np.concatenate([seq, e])) is not None:
                continue
            span = float(execute(acts, e, inst.drill_s).makespan[0])
            if best is None or span < best[0]:
                best = (span, u, v, trial)
        if best is None or len(flipped) >= limit:
            problem = f"cannot order {what}: no flip of their orders keeps the round free of deadlock"
            break
        flipped.add(frozenset((best[1], best[2])))
        edges = best[3]
    all_edges = np.array(sorted(edges), int).reshape(-1, 2)
    kept = reduce_edges(len(acts), seq, all_edges) if problem is None else all_edges
    timed = Actions(acts.booms, acts.hole_ids, acts.boom, acts.index, acts.kind, acts.hole, acts.src, acts.dst,
                    ex.start[0].copy(), ex.end[0].copy())
    zones, zone_stats = NO_ZONES, {"zones": 0}
    if problem is None and zone_search is not None:
        zones, kept, ex, nominal, timed, zone_stats = _with_zones(inst, acts, timed, all_edges, conf, oracle,
                                                                  zone_search, kept, ex, nominal)
    _, n_left, least = scan(nominal, oracle, full=True)
    stats = {"actions": len(acts), "pairs_screened": len(conf.pairs), "conflicting_pairs": len(pairs),
             "overlapping_in_plan": int(overlap.sum()), "interlocks_before_reduction": len(all_edges),
             "interlocks": len(kept), "flips": len(flipped), "conflicts_left": int(n_left),
             "min_clearance_m": float(least) if np.isfinite(least) else None,  # None: one boom, no pair
             "plan_makespan_s": tl.makespan,
             "nominal_makespan_s": nominal.makespan, "clearance_evaluations": conf.evaluations,
             "sweeps_s": swept, "build_s": time.perf_counter() - started, **zone_stats}
    return RobustRound(timed, kept, nominal, conf, stats, problem, zones)


def _with_zones(inst, acts, timed, all_edges, conf, oracle, zone_search, kept, ex, nominal):
    """Step 6: the zones chosen on the robust round, the interlocks they leave, the nominal round
    re-timed under the rule with them (scanned: were it not clear, the zones are dropped, said)."""
    zs, ds = zone_search
    d = draws(timed, ds)
    rand = np.flatnonzero([lab == "random" for lab in d.labels])[:zs.search_draws]
    factors = d.factors[rand] if len(rand) else d.factors[:1]
    K = len(acts)
    conflict = np.zeros((K, K), bool)
    pairs = conf.conflicting
    conflict[pairs[:, 0], pairs[:, 1]] = conflict[pairs[:, 1], pairs[:, 0]] = True
    choice = choose_zones(timed, all_edges, precedence_edges(inst, acts), conflict, inst.drill_s, factors, zs)
    stats = {f"zone_{k}" if not k.startswith("zone") else k: v for k, v in choice.stats.items()
             if k != "proof_problems"}
    stats["zone_proofs_refused"] = choice.stats.get("proof_problems", [])[:5]
    if not len(choice.zones):
        return NO_ZONES, kept, ex, nominal, timed, stats
    edges = reduce_edges(K, acts.sequence_edges(), choice.edges)
    ex_z = execute(acts, edges, inst.drill_s, choice.zones)
    _, nominal_z = realised(inst, acts, ex_z)
    if ex_z.deadlocked.any() or scan(nominal_z, oracle) is not None:  # the proof says it cannot happen: said
        stats.update(zones=0, zones_dropped="the nominal round with zones was not clear or deadlocked")
        return NO_ZONES, kept, ex, nominal, timed, stats
    timed_z = Actions(acts.booms, acts.hole_ids, acts.boom, acts.index, acts.kind, acts.hole, acts.src, acts.dst,
                      ex_z.start[0].copy(), ex_z.end[0].copy())
    return choice.zones, edges, ex_z, nominal_z, timed_z, stats


def _say(acts: Actions, s) -> str:
    if s[0] == "in":
        return acts.name(s[1])
    where = ("where it starts" if s[1] < 0 else "at park, done") if s[1] < 0 or s[2] < 0 else (
        f"between {acts.name(s[1])} and {acts.name(s[2])}")
    boom = acts.booms[acts.boom[s[1] if s[1] >= 0 else s[2]]]
    return f"boom {boom} standing {where}"
