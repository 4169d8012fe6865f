"""Plan a round: seed, route, time with waits, feed the conflicts back into the routing, repeat.

0. the sweeps (:mod:`pipeline.round.seeds`) and the spec's baselines (naive, nearest) are timed; the
   best is the first candidate and the routing's initial solution (so the optimised round is never
   worse than the better baseline);
1. :func:`pipeline.round.routing.route` allocates and orders the holes (makespan, no conflicts known);
2. every candidate's moves are looked at before it is timed (:class:`pipeline.round.detours.MoveBook`:
   a move that breaks self or tunnel clearance is re-planned, its detour's duration and motion used);
3. :func:`pipeline.round.waits.place_waits` times the routes with the waits that keep every boom-boom
   distance (``round.waits``: ``exact`` by CP-SAT, optimal for the routes; ``greedy``, the repair
   rule of :mod:`pipeline.round.timeline`, which falls back to one boom at a time; or the better);
4. every pair of holes (i on boom a, j on boom b: where each stood, or the hole it was moving to)
   whose conflict needed a wait is fed back (:mod:`pipeline.round.routing`: not drilled at the same
   time while on a and b; a soft same-boom cost where one boom can drill both), and the routing
   starts again from the best routes so far.

The best conflict-free timeline (fewest conflicts left, then makespan) is kept. **Why it ends:** step 4
runs only when the last timeline revealed a pair not yet fed back, a set that only grows and holds at
most (B H)^2 entries; at most ``reopt_rounds`` times; not once the best round is within ``stop_ratio``
of the lower bound; and, only where the opt-in wall-time ``budget_s`` is set (not reproducible), not
when the planning time left is less than one solve plus the last timing.
The move book looks at each of the B (H + 1)^2 moves at most once.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch

from pipeline.motion.checks import check_straight_moves
from pipeline.motion.path import unwrapped
from pipeline.round.baselines import naive_routes, nearest_routes
from pipeline.round.bounds import lower_bound
from pipeline.round.detours import PLANNED, RETRACT, MoveBook
from pipeline.round.instance import Instance, RoundSettings
from pipeline.round.oracle import ConflictOracle, KinematicOracle
from pipeline.round.routing import RoutingFailed, route
from pipeline.round.seeds import sweep_routes
from pipeline.round.timeline import Timeline
from pipeline.round.waits import place_waits


@dataclass
class RoundPlan:
    timeline: Timeline
    left_out: list[int]
    lower_bound_s: float
    rounds: int  # routing solves
    penalised: dict = field(default_factory=dict)  # hole pairs fed back -> seconds
    apart: list = field(default_factory=list)  # (i, a, j, b) fed back
    planning_s: float = 0.0
    seed: str | None = None  # the baseline the routing started from (also a candidate round)
    kept_seed: bool = False  # no routing solve beat the seed: the round is the seed baseline's
    baselines: dict = field(default_factory=dict)  # kind -> its timeline (the same conflict handling)
    inst: Instance | None = None  # the instance the timelines were timed on (detours' durations in move_s)
    book: MoveBook | None = None  # what is known of every move (straight, detour, failed)
    stopped: str = ""  # why the re-optimisation stopped
    baselines_s: float = 0.0  # seconds of planning_s spent timing the spec's baselines


SEEDS = ("sweep -y", "sweep +y")  # the planner's starts (pipeline.round.seeds)
BASELINES = ("naive", "nearest")  # the spec's, timed after the planning with the same moves and conflicts


def _better(a: Timeline, b: Timeline | None) -> bool:
    return b is None or (a.conflicts_left, a.makespan) < (b.conflicts_left, b.makespan)


class _Timer:
    """Routes -> timeline, every move looked at first (:meth:`MoveBook.ensure`): the one way the
    planner times a candidate, so that every candidate's moves are checked and priced alike."""

    def __init__(self, inst: Instance, oracle, settings: RoundSettings, book: MoveBook | None):
        self.inst, self.oracle, self.settings, self.book = inst, oracle, settings, book

    def __call__(self, routes: list[list[int]]) -> Timeline:
        if self.book is not None:
            self.inst = self.book.ensure(self.inst, routes)
        return place_waits(self.inst, routes, self.oracle, self.settings)


def make_book(inst: Instance, oracle, settings: RoundSettings) -> MoveBook | None:
    """The move book of a kinematic oracle (None for an oracle without a rig). With ``detours: false``
    it still certifies every move and fails those it cannot keep straight (never unchecked)."""
    if not isinstance(oracle, KinematicOracle):  # a planted conflict table: nothing to certify moves against
        return None
    return MoveBook(oracle, inst.n_holes, settings)


def plan_round(inst: Instance, oracle: ConflictOracle, settings: RoundSettings,
               progress: Callable[[str], None] | None = None,
               time_limit_s: float | None = None, book: MoveBook | None = None, baselines: bool = True,
               candidates: dict[str, list[list[int]]] | None = None) -> RoundPlan:
    """The round of ``inst`` (module docstring); ``book``: the move book to use (default
    :func:`make_book`); ``baselines``: time the spec's naive and nearest after the sweeps, as
    candidates and routing starts (``baselines`` of the plan, ``baselines_s`` of ``planning_s``);
    re-optimisation stops early when the best round is within
    ``settings.stop_ratio`` of the lower bound or the planning time passes ``settings.budget_s``."""
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    book = book if book is not None else make_book(inst, oracle, settings)
    if book is not None:  # a book given with moves already known (a round handed on): their detours' durations
        inst = book.apply(inst)
    timer = _Timer(inst, oracle, settings, book)
    lb = lower_bound(inst)
    best, seed, done = None, None, {}
    baselines_s = 0.0
    last_timing = 0.0  # seconds the last candidate took to time (moves looked at, waits): the next one's estimate
    seeds = {kind: seed_routes(inst, kind, settings.sweep_band_m) for kind in SEEDS} if seeded(inst) else {}
    seeds.update({k: first_where_standing(inst, r) for k, r in (candidates or {}).items()})  # the caller's too
    if seeds:  # the sweeps (and given candidates), timed: the best is a candidate and the routing's start
        for kind, routes in seeds.items():
            t_timing = time.perf_counter()
            tl = timer(routes)
            last_timing = max(last_timing, time.perf_counter() - t_timing)
            say(f"seed {kind}: makespan {tl.makespan:.1f} s, {tl.conflicts_left} conflicts left")
            if _better(tl, best):
                best, seed = tl, kind
        t_base = time.perf_counter()
        for kind in BASELINES if baselines and seeded(inst) else ():  # the spec's rounds: reported, and candidates (so
            tl = done[kind] = timer(seed_routes(inst, kind))  # the routing can start from, and beat, them)
            say(f"baseline {kind}: makespan {tl.makespan:.1f} s, {tl.conflicts_left} conflicts left")
            if _better(tl, best):
                best, seed = tl, kind
        baselines_s = time.perf_counter() - t_base

    # Wall time is opt-in (round.budget_s, round.time_limit_s): without it no decision reads a clock.
    base_limit = time_limit_s if time_limit_s is not None else settings.time_limit_s

    def remaining() -> float:
        return math.inf if settings.budget_s is None else settings.budget_s - (time.perf_counter() - t0)

    def limit() -> float | None:
        if base_limit is None and settings.budget_s is None:
            return None  # counts only: round.solution_limit
        return max(0.1, min(base_limit if base_limit is not None else math.inf, remaining()))

    def out_of_budget() -> bool:  # the next solve (its time limit, if any) and its timing would pass budget_s
        return settings.budget_s is not None and remaining() < (base_limit or 0.0) + last_timing

    routing = best is None or (settings.routing and not out_of_budget())  # at least one solve, budget allowing
    blocked = None
    # (not for a round handed on: its booms do not start at park, and its re-planning is on the clock)
    if routing and settings.blocked_penalty_s > 0 and inst.n_booms > 1 and inst.start is None:
        blocked = park_blocked(inst, oracle, settings.blocked_neighbours, settings.blocked_screen_m)
        say(f"moves blocked by another boom at park: {int(blocked.sum())} of the {settings.blocked_neighbours} "
            "shortest per node (penalised in the routing)")

    def costed() -> Instance:
        cur = timer.inst
        if blocked is None:
            return cur
        penalty = blocked.copy()
        if book is not None:  # a detour was planned clear of the other booms at park
            penalty &= (book.status != RETRACT) & (book.status != PLANNED)
        return replace(cur, move_s=cur.move_s + settings.blocked_penalty_s * penalty)

    penalised: dict[tuple[int, int], float] = {}
    apart: set[tuple[int, int, int, int]] = set()
    stopped = ""
    rounds = 0
    r = None
    if not routing:
        stopped = ("round.routing = false: the best seed" if not settings.routing else
                   f"budget_s ({settings.budget_s:g} s): the seeds left too little for a routing solve and its timing")
    else:
        r = route(costed(), settings, time_limit_s=limit(), initial=None if best is None else best.routes)
        rounds = 1
    for it in range(settings.reopt_rounds + 1):
        if r is None:
            break
        t_timing = time.perf_counter()
        tl = timer(r.routes)
        say(f"round {it}: makespan {tl.makespan:.1f} s, {len(tl.repairs)} waits, {tl.conflicts_left} conflicts left")
        if _better(tl, best):
            best = tl
        alt = reversed_variant(timer, r.routes, inst)
        if alt is not None and _better(alt, best):
            say(f"round {it}, one boom reversed: makespan {alt.makespan:.1f} s, {alt.conflicts_left} conflicts left")
            best = alt
        last_timing = time.perf_counter() - t_timing
        new, new_apart = {}, set()
        for rec in tl.repairs:
            (i, j), (a, b) = rec["nodes"], rec["booms"]
            if max(i, j) >= inst.n_holes or i == j:
                continue
            if (i, a, j, b) not in apart and (j, b, i, a) not in apart:
                new_apart.add((i, a, j, b))
            key = (min(i, j), max(i, j))
            if key not in penalised and (inst.reach[:, i] & inst.reach[:, j]).any():
                new[key] = max(new.get(key, 0.0), rec["wait_s"])
        if best.conflicts_left == 0 and best.makespan <= settings.stop_ratio * lb:
            stopped = f"within stop_ratio {settings.stop_ratio} of the lower bound"
            break
        if not (new or new_apart):
            stopped = "no new conflict pair to feed back"
            break
        if it == settings.reopt_rounds:
            stopped = f"reopt_rounds ({settings.reopt_rounds}) done"
            break
        if out_of_budget():
            stopped = f"budget_s ({settings.budget_s:g} s): no time left for another routing solve"
            break
        penalised.update(new)
        apart |= new_apart
        try:
            r = route(costed(), settings, same_boom=penalised, apart=sorted(apart), initial=best.routes,
                      time_limit_s=limit())
        except RoutingFailed as e:  # the fed-back pairs left the first-solution heuristic no routes: keep the best
            stopped = f"the routing found no routes with the {len(apart)} pairs fed back ({e})"
            break
        rounds += 1
    if best is None:  # cannot happen: without a candidate the routing always runs
        raise RuntimeError("round: no candidate timeline")
    planning_s = time.perf_counter() - t0
    kept = seed is not None and best.routes == (seeds[seed] if seed in seeds else seed_routes(inst, seed))
    left_out = [int(h) for h in np.flatnonzero(~inst.drillable)]
    say(f"stopped: {stopped}")
    return RoundPlan(best, left_out, lb, rounds, penalised, sorted(apart), planning_s,
                     seed, kept, done, timer.inst, book, stopped, baselines_s)


def _reverse_one(routes: list[list[int]], b: int) -> list[list[int]]:
    return [list(r[::-1]) if k == b else list(r) for k, r in enumerate(routes)]


def reversed_variant(timer: Callable[[list[list[int]]], Timeline], routes: list[list[int]],
                     inst: Instance) -> Timeline | None:
    """The best timeline of ``routes`` with one boom's order reversed (each boom in turn), or None.

    Two booms that start on neighbouring holes of the face's middle tend to block each other's next
    moves (no wait parts them: the timeline falls back to one boom at a time); one boom drilling its
    holes the other way round keeps them apart. Without precedence pairs only (reversing would break
    them); cheap (a timeline per boom), so every routing solve's routes are tried both ways.
    ``timer``: routes -> timeline (the planner's, which looks at every move first)."""
    if inst.precedence or inst.n_booms < 2 or inst.start is not None:  # a handed-on route's first hole is fixed
        return None
    best = None
    for b in range(inst.n_booms):
        if len(routes[b]) < 2:
            continue
        tl = timer(_reverse_one(routes, b))
        if _better(tl, best):
            best = tl
    return best


def park_blocked(inst: Instance, oracle, neighbours: int = 12, screen_m: float = 0.05) -> np.ndarray:
    """``(B, H + 1, H + 1)`` bool: boom a's straight move u -> v passes within the oracle's margin of
    some other boom standing at its park. Such a move can never run while that boom is home (at the
    start or the end of the round), and waits cannot part them; the routing pays
    ``blocked_penalty_s`` for each. A routing cost, not a check (the timeline's oracle checks every
    move): only each node's ``neighbours`` shortest moves out and in are screened (the routing
    uses short moves; others stay unpenalised), sampled every ``screen_m`` of point travel, all in
    one batch per boom (:func:`pipeline.motion.checks.check_straight_moves`)."""
    B, H = inst.n_booms, inst.n_holes
    bad = np.zeros((B, H + 1, H + 1), bool)
    if not isinstance(oracle, KinematicOracle):
        return bad
    rig = oracle.rig
    for a in range(B):
        ok = np.concatenate([inst.reach[a], [True]])
        nodes = np.flatnonzero(ok)
        if len(nodes) < 2:
            continue
        mv = inst.move_s[a][np.ix_(nodes, nodes)].astype(float)
        np.fill_diagonal(mv, np.inf)
        k = min(neighbours, len(nodes) - 1)
        near = np.zeros(mv.shape, bool)
        rows = np.arange(len(nodes))[:, None]
        near[rows, np.argsort(mv, axis=1)[:, :k]] = True  # each node's k shortest moves out ...
        near |= near.T  # ... and their reverses (the same configurations backwards)
        near[:, nodes == H] = near[nodes == H, :] = True  # every move from and to park
        np.fill_diagonal(near, False)
        iu, iv = np.nonzero(near)
        u, v = nodes[iu], nodes[iv]
        q = oracle.joints[a]
        qa = q[torch.as_tensor(u)]
        qb = unwrapped(qa, q[torch.as_tensor(v)], oracle.limits[a])
        checks = check_straight_moves(rig, a, qa, qb, resolution=screen_m, boom_only=True)
        bad[a, u, v] = ~checks.clear(margin=oracle.margin).numpy()
    return bad


def seeded(inst: Instance) -> bool:
    """Whether the instance carries what the baselines need (collars, base y, park points)."""
    return inst.collars is not None and inst.base_y is not None and inst.park_points is not None


def seed_routes(inst: Instance, kind: str, band_m: float = 1.0) -> list[list[int]]:
    """The routes of a seed: the spec's ``naive`` and ``nearest``, or a sweep (:mod:`pipeline.round.seeds`)."""
    if kind.startswith("sweep"):
        routes = sweep_routes(inst, -1 if "-y" in kind else 1, band_m * (2 if kind.endswith("wide") else 1))
    else:
        routes = {"naive": naive_routes, "nearest": nearest_routes}[kind](inst)
    return first_where_standing(inst, routes)


def first_where_standing(inst: Instance, routes: list[list[int]]) -> list[list[int]]:
    """A round handed on: a boom standing at a hole it has not drilled drills it first (the routing's
    rule, :mod:`pipeline.round.routing`); other routes as they are."""
    if inst.start is None:
        return routes
    out = [list(r) for r in routes]
    for b, s in enumerate(inst.starts):
        if s < inst.n_holes and inst.reach[b, s] and s in out[b]:
            out[b].remove(s)
            out[b].insert(0, s)
    return out


def baseline(inst: Instance, oracle, kind: str, settings: RoundSettings, book: MoveBook | None = None) -> Timeline:
    """The spec's ``naive`` or ``nearest`` round, with the same conflict handling (and, given the
    planner's ``book``, the same moves)."""
    return timed_routes(inst, oracle, settings, book, seed_routes(inst, kind))


def timed_routes(inst: Instance, oracle, settings: RoundSettings, book: MoveBook | None,
                 routes: list[list[int]]) -> Timeline:
    """Given routes timed as the planner times a candidate (every move looked at, waits inserted)."""
    return _Timer(inst, oracle, settings, book)(routes)
