"""Plan a round: route, time with waits, feed the conflicts back into the routing, repeat.

0. the spec's baselines (naive, nearest) are timed with the same conflict handling; the better one
   is the first candidate and the routing's initial solution (so the optimised round is never worse
   than the better baseline);
1. :func:`pipeline.round.routing.route` allocates and orders the holes (makespan, no conflicts known);
2. :func:`pipeline.round.timeline.resolve` times the routes and inserts waits until no boom-boom
   conflict is left (or falls back to one boom at a time, checked);
3. every pair of holes (i on boom a, j on boom b: where each stood, or the hole it was moving to)
   whose conflict needed a wait is fed back (:mod:`pipeline.round.routing`: not drilled at the same
   time while on a and b; a soft same-boom cost where one boom can drill both), and the routing
   starts again from the last routes.

The best conflict-free timeline (fewest conflicts left, then makespan) is kept. **Why it ends:** step 3
runs only when the last timeline revealed a pair not yet fed back, a set that only grows and holds at
most (B H)^2 entries; and at most ``reopt_rounds`` times (config).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from pipeline.round.baselines import naive_routes, nearest_routes
from pipeline.round.bounds import lower_bound
from pipeline.round.instance import Instance, RoundSettings
from pipeline.round.routing import route
from pipeline.round.timeline import Timeline, resolve


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


def _better(a: Timeline, b: Timeline | None) -> bool:
    return b is None or (a.conflicts_left, a.makespan) < (b.conflicts_left, b.makespan)


def plan_round(inst: Instance, oracle, settings: RoundSettings, progress: Callable[[str], None] | None = None,
               time_limit_s: float | None = None) -> RoundPlan:
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    best, seed, done = None, None, {}
    if seeded(inst):  # the spec's baselines, timed: the routing starts from the better one, and it is a candidate
        for kind in ("naive", "nearest"):
            tl = done[kind] = baseline(inst, oracle, kind, settings)
            say(f"seed {kind}: makespan {tl.makespan:.1f} s, {tl.conflicts_left} conflicts left")
            if _better(tl, best):
                best, seed = tl, kind
            alt = reversed_variant(inst, oracle, settings, tl.routes)
            if alt is not None and _better(alt, best):
                say(f"seed {kind}, one boom reversed: makespan {alt.makespan:.1f} s, {alt.conflicts_left} conflicts")
                best, seed = alt, f"{kind} (one boom reversed)"
    blocked = park_blocked(inst, oracle) if settings.blocked_penalty_s > 0 and inst.n_booms > 1 else None
    costed = inst if blocked is None else replace(inst, move_s=inst.move_s + settings.blocked_penalty_s * blocked)
    if blocked is not None:
        say(f"moves blocked by another boom at park: {int(blocked.sum())} of {blocked.size} (penalised in the routing)")
    r = route(costed, settings, time_limit_s=time_limit_s, initial=None if best is None else best.routes)
    penalised: dict[tuple[int, int], float] = {}
    apart: set[tuple[int, int, int, int]] = set()
    rounds = 1
    for it in range(settings.reopt_rounds + 1):
        tl = resolve(inst, r.routes, oracle, settings.max_repairs)
        say(f"round {it}: makespan {tl.makespan:.1f} s, {len(tl.repairs)} waits, {tl.conflicts_left} conflicts left")
        if _better(tl, best):
            best = tl
        alt = reversed_variant(inst, oracle, settings, r.routes)
        if alt is not None and _better(alt, best):
            say(f"round {it}, one boom reversed: makespan {alt.makespan:.1f} s, {alt.conflicts_left} conflicts left")
            best = alt
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
        if not (new or new_apart) or it == settings.reopt_rounds:
            break
        penalised.update(new)
        apart |= new_apart
        r = route(costed, settings, same_boom=penalised, apart=sorted(apart), initial=best.routes,
                  time_limit_s=time_limit_s)
        rounds += 1
    return RoundPlan(best, r.left_out, lower_bound(inst), rounds, penalised, sorted(apart), time.perf_counter() - t0,
                     seed, best is not None and seed is not None and best.routes in (
                         seed_routes(inst, seed.split(" ")[0]),
                         *(_reverse_one(seed_routes(inst, seed.split(" ")[0]), b) for b in range(inst.n_booms))), done)


def _reverse_one(routes: list[list[int]], b: int) -> list[list[int]]:
    return [list(r[::-1]) if k == b else list(r) for k, r in enumerate(routes)]


def reversed_variant(inst: Instance, oracle, settings: RoundSettings, routes: list[list[int]]) -> Timeline | None:
    """The best timeline of ``routes`` with one boom's order reversed (each boom in turn), or None.

    Two booms that start on neighbouring holes of the face's middle tend to block each other's next
    moves (no wait parts them: the timeline falls back to one boom at a time); one boom drilling its
    holes the other way round keeps them apart. Without precedence pairs only (reversing would break
    them); cheap (a timeline per boom), so every routing solve's routes are tried both ways."""
    if inst.precedence or inst.n_booms < 2:
        return None
    best = None
    for b in range(inst.n_booms):
        if len(routes[b]) < 2:
            continue
        tl = resolve(inst, _reverse_one(routes, b), oracle, settings.max_repairs)
        if _better(tl, best):
            best = tl
    return best


def park_blocked(inst: Instance, oracle) -> np.ndarray:
    """``(B, H + 1, H + 1)`` bool: boom a's straight move u -> v conflicts with some other boom standing at
    its park (the oracle's rule). Such a move can never run while that boom is home (at the start or
    the end of the round), and waits cannot part them; the routing pays ``blocked_penalty_s`` for each."""
    B, H = inst.n_booms, inst.n_holes
    bad = np.zeros((B, H + 1, H + 1), bool)
    park = {"t0": 0.0, "t1": np.inf, "u": H, "v": H, "k": -1}
    for a in range(B):
        ok = np.concatenate([inst.reach[a], [True]])
        u, v = np.nonzero(ok[:, None] & ok[None, :] & ~np.eye(H + 1, dtype=bool))
        dur = inst.move_s[a, u, v]
        mv = {"t0": np.zeros(len(u)), "t1": dur, "u": u, "v": v, "k": np.zeros(len(u), int)}
        for b in range(B):
            if b == a or not len(u):
                continue
            other = {k: np.full(len(u), x) for k, x in park.items()}
            lo = np.zeros(len(u))
            first, _ = oracle.check(a, mv, b, other, lo, dur) if a < b else oracle.check(b, other, a, mv, lo, dur)
            bad[a, u, v] |= np.isfinite(first)
    return bad


def seeded(inst: Instance) -> bool:
    """Whether the instance carries what the baselines need (collars, base y, park points)."""
    return inst.collars is not None and inst.base_y is not None and inst.park_points is not None


def seed_routes(inst: Instance, kind: str) -> list[list[int]]:
    return {"naive": naive_routes, "nearest": nearest_routes}[kind](inst)


def baseline(inst: Instance, oracle, kind: str, settings: RoundSettings) -> Timeline:
    """The spec's ``naive`` or ``nearest`` round, with the same conflict handling."""
    return resolve(inst, seed_routes(inst, kind), oracle, settings.max_repairs)
