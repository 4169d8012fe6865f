"""Plan a round: seed, route, time with waits, feed the conflicts back into the routing, repeat.

0. the sweeps (:mod:`pipeline.round.seeds`, in bands of ``sweep_band_m`` and ``sweep_more_bands_m``, each
   also with each boom's first and last hole one it can reach from park while the others stand there:
   :func:`pipeline.round.seeds.clear_ends`) and the reference's baselines (naive, nearest) are timed
   (``_time_seeds``); the best is the first candidate and the routing's initial solution (so the
   optimised round is never worse than the better baseline);
1. :func:`pipeline.round.routing.route` allocates and orders the holes (makespan, no conflicts known; moves
   another boom at park blocks cost more: ``_routing_costs``);
2. every candidate's moves are looked at before it is timed (:class:`pipeline.round.detours.MoveBook`:
   a move that breaks self or tunnel clearance is re-planned, its detour's duration and motion used);
3. :func:`pipeline.round.waits.place_waits` times the routes with the waits that keep every boom-boom
   distance (``round.waits``: ``exact`` by CP-SAT, optimal for the routes; ``greedy``, the repair
   rule of :mod:`pipeline.round.timeline`, which falls back to one boom at a time; or the better);
4. (``_conflicts_to_feed_back``) every pair of holes (i on boom a, j on boom b: where each stood, or
   the hole it was moving to) whose conflict needed a wait is fed back (:mod:`pipeline.round.routing`:
   not drilled at the same time while on a and b; a soft same-boom cost where one boom can drill both),
   and the routing starts again from the best routes so far.

The best conflict-free timeline (fewest conflicts left, then makespan) is kept. **Why it ends** (``_why_stop``): step 4
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

from pipeline.core.signals import raise_if_terminated
from pipeline.motion.checks import check_straight_moves
from pipeline.motion.path import unwrapped
from pipeline.round.baselines import naive_routes, nearest_routes
from pipeline.round.bounds import lower_bound
from pipeline.round.detours import PLANNED, RETRACT, MoveBook
from pipeline.round.oracle import ConflictOracle, KinematicOracle
from pipeline.round.problem import Instance
from pipeline.round.routing import RoutingFailed, route
from pipeline.round.seeds import clear_ends, sweep_routes
from pipeline.round.settings import RoundSettings
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
    baselines_s: float = 0.0  # seconds of planning_s spent timing the reference's baselines
    postures: dict | None = None  # the posture choice (pipeline.round.postures), where it ran
    timed: dict = field(default_factory=dict)  # label -> every candidate timeline this planning timed


SEEDS = ("sweep -y", "sweep +y")  # the planner's starts (pipeline.round.seeds)
BASELINES = ("naive", "nearest")  # the reference's, timed after the planning with the same moves and conflicts


def better(a: Timeline, b: Timeline | None) -> bool:
    """Fewer conflicts left, then fewer failed moves, then the shorter makespan: a round with a move
    nothing made clear is published only where no candidate has all its moves clear."""
    return b is None or (a.conflicts_left, a.failed_moves, a.makespan) < (b.conflicts_left, b.failed_moves,
                                                                         b.makespan)


class _Timer:
    """Routes -> timeline, every move looked at first (:meth:`MoveBook.ensure`): the one way the
    planner times a candidate, so that every candidate's moves are checked and priced alike."""

    def __init__(self, inst: Instance, oracle, settings: RoundSettings, book: MoveBook | None):
        self.inst, self.oracle, self.settings, self.book = inst, oracle, settings, book

    def __call__(self, routes: list[list[int]]) -> Timeline:
        raise_if_terminated()  # between candidates: a signal OR-Tools' callbacks swallowed stops the planning here
        if self.book is not None:
            self.inst = self.book.ensure(self.inst, routes)
        tl = place_waits(self.inst, routes, self.oracle, self.settings)
        if self.book is not None:
            tl.failed_moves = len(self.book.kinds(routes, self.inst.starts)[1])
        return tl


def make_book(inst: Instance, oracle, settings: RoundSettings) -> MoveBook | None:
    """The move book of a kinematic oracle (None for an oracle without a rig). With ``detours: false``
    it still certifies every move and fails those it cannot keep straight (never unchecked)."""
    if not isinstance(oracle, KinematicOracle):  # a planted conflict table: nothing to certify moves against
        return None
    return MoveBook(oracle, inst.n_holes, settings)


class _Clock:
    """The opt-in wall time (``round.budget_s``, ``round.time_limit_s``): without either, no decision
    of the planner reads a clock (counts only: ``round.solution_limit``, ``round.search_checks``)."""

    def __init__(self, settings: RoundSettings, time_limit_s: float | None):
        self.t0 = time.perf_counter()
        self.budget_s = settings.budget_s
        self.base_limit = time_limit_s if time_limit_s is not None else settings.time_limit_s
        self.last_timing = 0.0  # seconds the last candidate took to time: the next one's estimate

    def remaining(self) -> float:
        return math.inf if self.budget_s is None else self.budget_s - (time.perf_counter() - self.t0)

    def limit(self) -> float | None:
        """The next routing solve's time limit (None: counts only)."""
        if self.base_limit is None and self.budget_s is None:
            return None
        return max(0.1, min(self.base_limit if self.base_limit is not None else math.inf, self.remaining()))

    def out_of_budget(self) -> bool:
        """The next solve (its time limit, if any) and its timing would pass ``budget_s``."""
        return self.budget_s is not None and self.remaining() < (self.base_limit or 0.0) + self.last_timing

    def timed(self, timer: _Timer, routes: list[list[int]]) -> Timeline:
        started = time.perf_counter()
        tl = timer(routes)
        self.last_timing = max(self.last_timing, time.perf_counter() - started)
        return tl


@dataclass
class _Start:
    """Step 0's answer: the best candidate so far and where it came from."""

    best: Timeline | None = None
    seed: str | None = None
    seeds: dict = field(default_factory=dict)  # kind -> routes (the sweeps and the caller's candidates)
    baselines: dict = field(default_factory=dict)  # kind -> timeline of the reference's baselines
    baselines_s: float = 0.0
    timed: dict = field(default_factory=dict)  # kind -> timeline of every candidate timed


def _time_seeds(inst: Instance, timer: _Timer, clock: _Clock, settings: RoundSettings, baselines: bool,
                candidates: dict[str, list[list[int]]] | None, say: Callable[[str], None]) -> _Start:
    """Step 0: the sweeps, the caller's candidates and (``baselines``) the reference's naive and nearest,
    each timed; the best is the first candidate and the routing's initial solution."""
    start = _Start()
    if seeded(inst):
        start.seeds = sweeps(inst, timer.oracle, settings, settings.sweep_band_m, settings.sweep_more_bands_m)
    start.seeds.update({k: first_where_standing(inst, r) for k, r in (candidates or {}).items()})
    if not start.seeds:
        return start
    for kind, routes in start.seeds.items():
        tl = start.timed[kind] = clock.timed(timer, routes)
        say(f"seed {kind}: makespan {tl.makespan:.1f} s, {tl.conflicts_left} conflicts left")
        if better(tl, start.best):
            start.best, start.seed = tl, kind
    t_base = time.perf_counter()
    for kind in BASELINES if baselines and seeded(inst) else ():  # reported, and candidates the routing can beat
        tl = start.baselines[kind] = start.timed[kind] = timer(seed_routes(inst, kind))
        say(f"baseline {kind}: makespan {tl.makespan:.1f} s, {tl.conflicts_left} conflicts left")
        if better(tl, start.best):
            start.best, start.seed = tl, kind
    start.baselines_s = time.perf_counter() - t_base
    return start


def sweeps(inst: Instance, oracle, settings: RoundSettings, band_m: float | None, more_bands_m) -> dict:
    """The sweep seeds (kind -> routes): both directions in bands of ``band_m`` (named by direction
    alone; None: none) and of each of ``more_bands_m``, and (``round.clear_ends``) each also with its
    ends clear of the other booms' parks where that changes it; each set of routes once."""
    seeds: dict = {}
    if band_m is not None:
        seeds = {kind: seed_routes(inst, kind, band_m) for kind in SEEDS}
    for band in more_bands_m:  # the best band depends on the face (docs/design.md)
        for kind in SEEDS:
            _add_seed(seeds, f"{kind}, band {band:g} m", seed_routes(inst, kind, band))
    if settings.clear_ends and inst.start is None and inst.n_booms > 1 and isinstance(oracle, KinematicOracle):
        # each sweep also with ends clear of the other booms' parks, where that changes it (both timed:
        # a blocked first move is often cleared by a wait, the other boom leaving park at the start)
        blocked = park_blocked(inst, oracle, 0, settings.blocked_screen_m)  # the moves from and to park
        for kind, routes in list(seeds.items()):
            _add_seed(seeds, f"{kind}, ends clear", clear_ends(routes, blocked, inst.precedence))
    return seeds


def time_more_sweeps(rp: RoundPlan, oracle, settings: RoundSettings, bands_m) -> int:
    """Sweeps in the bands ``bands_m`` timed on the plan's instance as the planner times a candidate,
    into ``rp.timed`` (those whose routes the planning timed already are not timed again), for the
    robust choice (``round.robust_bands_m``); the plan's instance takes the new moves' detours. How
    many were timed."""
    if not seeded(rp.inst) or not bands_m:
        return 0
    timer = _Timer(rp.inst, oracle, settings, rp.book)
    n = 0
    for kind, routes in sweeps(rp.inst, oracle, settings, None, bands_m).items():
        if all(routes != tl.routes for tl in rp.timed.values()):
            rp.timed[kind] = timer(routes)
            n += 1
    rp.inst = timer.inst
    return n


def _add_seed(seeds: dict, kind: str, routes: list[list[int]]) -> None:
    """``routes`` as seed ``kind``, unless a seed already has them (timed once)."""
    if all(routes != r for r in seeds.values()):
        seeds[kind] = routes


def _routing_costs(inst: Instance, oracle, settings: RoundSettings, book: MoveBook | None,
                   say: Callable[[str], None]) -> Callable[[Instance], Instance]:
    """Step 1's costs: the instance's move times plus ``blocked_penalty_s`` for each move another boom
    at park blocks (:func:`park_blocked`), unless a detour was planned clear of it. Not for a round
    handed on: its booms do not start at park."""
    if settings.blocked_penalty_s <= 0 or inst.n_booms < 2 or inst.start is not None:
        return lambda cur: cur
    blocked = park_blocked(inst, oracle, settings.blocked_neighbours, settings.blocked_screen_m)
    say(f"moves blocked by another boom at park: {int(blocked.sum())} of the {settings.blocked_neighbours} "
        "shortest per node (penalised in the routing)")

    def costed(cur: Instance) -> Instance:
        penalty = blocked.copy()
        if book is not None:
            penalty &= (book.status != RETRACT) & (book.status != PLANNED)
        return replace(cur, move_s=cur.move_s + settings.blocked_penalty_s * penalty)

    return costed


def _conflicts_to_feed_back(tl: Timeline, inst: Instance, penalised: dict, apart: set) -> tuple[dict, set]:
    """Step 4: the hole pairs whose conflict needed a wait in ``tl`` and are not fed back yet: ``(i, a,
    j, b)`` apart (not drilled at the same time on a and b) and, where one boom can drill both, a
    same-boom cost of the longest wait."""
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
    return new, new_apart


def _why_stop(best: Timeline, lb: float, it: int, fresh: bool, settings: RoundSettings, clock: _Clock) -> str:
    """Why the re-optimisation ends after round ``it`` (module docstring), or "" to go on;
    ``fresh``: the last timeline revealed a pair not yet fed back."""
    if best.conflicts_left == 0 and best.makespan <= settings.stop_ratio * lb:
        return f"within stop_ratio {settings.stop_ratio} of the lower bound"
    if not fresh:
        return "no new conflict pair to feed back"
    if it == settings.reopt_rounds:
        return f"reopt_rounds ({settings.reopt_rounds}) done"
    if clock.out_of_budget():
        return f"budget_s ({settings.budget_s:g} s): no time left for another routing solve"
    return ""


def plan_round(inst: Instance, oracle: ConflictOracle, settings: RoundSettings,
               progress: Callable[[str], None] | None = None,
               time_limit_s: float | None = None, book: MoveBook | None = None, baselines: bool = True,
               candidates: dict[str, list[list[int]]] | None = None) -> RoundPlan:
    """The round of ``inst``, by the module docstring's steps; ``book``: the move book to use (default
    :func:`make_book`; one given with moves already known, as for a round handed on, lends their
    detours' durations); ``baselines``: time the reference's naive and nearest after the sweeps, as
    candidates and routing starts (``baselines`` of the plan, ``baselines_s`` of ``planning_s``);
    ``candidates``: more routes to time in step 0 (kind -> routes)."""
    clock = _Clock(settings, time_limit_s)
    say = progress or (lambda _msg: None)
    book = book if book is not None else make_book(inst, oracle, settings)
    if book is not None:
        inst = book.apply(inst)
    timer = _Timer(inst, oracle, settings, book)  # step 2: every candidate's moves looked at, then step 3
    lb = lower_bound(inst)
    start = _time_seeds(inst, timer, clock, settings, baselines, candidates, say)  # step 0
    best = start.best
    routing = best is None or (settings.routing and not clock.out_of_budget())  # at least one solve
    penalised: dict[tuple[int, int], float] = {}
    apart: set[tuple[int, int, int, int]] = set()
    rounds, r = 0, None
    costed = _routing_costs(inst, oracle, settings, book, say) if routing else (lambda cur: cur)
    if routing:  # step 1
        r = route(costed(timer.inst), settings, time_limit_s=clock.limit(),
                  initial=None if best is None else best.routes)
        rounds, stopped = 1, ""
    else:
        stopped = ("round.routing = false: the best seed" if not settings.routing else
                   f"budget_s ({settings.budget_s:g} s): the seeds left too little for a routing solve and its timing")
    for it in range(settings.reopt_rounds + 1):
        if r is None:
            break
        t_timing = time.perf_counter()
        tl = start.timed[f"routing {it}"] = timer(r.routes)  # steps 2 and 3
        say(f"round {it}: makespan {tl.makespan:.1f} s, {len(tl.repairs)} waits, {tl.conflicts_left} conflicts left")
        if better(tl, best):
            best = tl
        alt = reversed_variant(timer, r.routes, inst)
        if alt is not None:
            start.timed[f"routing {it}, one boom reversed"] = alt
        if alt is not None and better(alt, best):
            say(f"round {it}, one boom reversed: makespan {alt.makespan:.1f} s, {alt.conflicts_left} conflicts left")
            best = alt
        clock.last_timing = time.perf_counter() - t_timing
        new, new_apart = _conflicts_to_feed_back(tl, inst, penalised, apart)  # step 4
        stopped = _why_stop(best, lb, it, bool(new or new_apart), settings, clock)
        if stopped:
            break
        penalised.update(new)
        apart |= new_apart
        try:
            r = route(costed(timer.inst), settings, same_boom=penalised, apart=sorted(apart), initial=best.routes,
                      time_limit_s=clock.limit())
        except RoutingFailed as e:  # the fed-back pairs left the first-solution heuristic no routes: keep the best
            stopped = f"the routing found no routes with the {len(apart)} pairs fed back ({e})"
            break
        rounds += 1
    if best is None:  # cannot happen: without a candidate the routing always runs
        raise RuntimeError("round: no candidate timeline")
    planning_s = time.perf_counter() - clock.t0
    seed = start.seed
    kept = seed is not None and best.routes == (start.seeds[seed] if seed in start.seeds else seed_routes(inst, seed))
    left_out = [int(h) for h in np.flatnonzero(~inst.drillable)]
    say(f"stopped: {stopped}")
    return RoundPlan(best, left_out, lb, rounds, penalised, sorted(apart), planning_s,
                     seed, kept, start.baselines, timer.inst, book, stopped, start.baselines_s, timed=start.timed)


def near_best(rp: RoundPlan, slack: float, count: int) -> list[tuple[str, Timeline]]:
    """The plan's best round and up to ``count - 1`` other candidates it timed that are as good on
    every count (conflicts left, failed moves, the one-boom fallback) and whose makespan is within
    ``slack`` (a share) of the best's: the shortest first, each set of routes once. What the round made
    robust chooses among (:func:`pipeline.round.from_plan.schedule_round`, ``choose``)."""
    best = rp.timeline
    out: list[tuple[str, Timeline]] = [("best", best)]
    key = (best.conflicts_left, best.failed_moves, best.sequential)
    near = sorted(((label, tl) for label, tl in rp.timed.items()
                   if (tl.conflicts_left, tl.failed_moves, tl.sequential) == key
                   and tl.makespan <= best.makespan * (1 + slack)), key=lambda c: c[1].makespan)
    for label, tl in near:
        if len(out) >= count:
            break
        if all(tl.routes != t.routes for _, t in out):
            out.append((label, tl))
    return out


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
        if better(tl, best):
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
    """The routes of a seed: the reference's ``naive`` and ``nearest``, or a sweep (:mod:`pipeline.round.seeds`)."""
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
    """The reference's ``naive`` or ``nearest`` round, with the same conflict handling (and, given the
    planner's ``book``, the same moves)."""
    return timed_routes(inst, oracle, settings, book, seed_routes(inst, kind))


def timed_routes(inst: Instance, oracle, settings: RoundSettings, book: MoveBook | None,
                 routes: list[list[int]]) -> Timeline:
    """Given routes timed as the planner times a candidate (every move looked at, waits inserted)."""
    return _Timer(inst, oracle, settings, book)(routes)
