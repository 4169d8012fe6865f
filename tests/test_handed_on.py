"""A round handed on from where the booms stand (``Instance.start``): the routing, the timeline and the
bound, on small synthetic instances checked against brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pipeline.core.errors import ConfigError
from pipeline.round.bounds import lower_bound
from pipeline.round.problem import Instance
from pipeline.round.routing import route
from pipeline.round.settings import RoundSettings
from pipeline.round.timeline import simulate


def line_instance(start=None, H=5, seed=0):
    """Holes on a line; boom b's park at x = -1 (b = 0) or x = H (b = 1); moves take |dx| s; drills 10-30 s."""
    rng = np.random.default_rng(seed)
    x = np.concatenate([np.arange(H, dtype=float), [np.nan]])
    move = np.zeros((2, H + 1, H + 1))
    for b, park in enumerate((-1.0, float(H))):
        xb = x.copy()
        xb[H] = park
        move[b] = np.abs(xb[:, None] - xb[None, :])
    phases = np.stack([np.full(H, 5.0), rng.uniform(5, 25, H), np.zeros(H)], 1)
    return Instance(("L", "R"), tuple(f"h{i}" for i in range(H)), np.ones((2, H), bool), phases, move, start=start)


def makespan_by_hand(inst: Instance, routes) -> float:
    """The makespan of routes on an instance without conflicts or precedence, summed by hand (not the
    timeline's code): each boom from the node it stands at, every move then its hole's drilling, and
    home to its park; the longest boom's time."""
    park = inst.n_holes
    longest = 0.0
    for b, route_b in enumerate(routes):
        node, t = inst.starts[b], 0.0
        for h in route_b:
            t += inst.move_s[b, node, h] + inst.drill_s[h]
            node = h
        longest = max(longest, t + inst.move_s[b, node, park])
    return longest


def brute_force(inst: Instance) -> float:
    """The shortest makespan over every allocation and order of the drillable holes (no conflicts), each
    boom standing at an undrilled hole drilling it first, timed by :func:`makespan_by_hand`."""
    holes = [h for h in range(inst.n_holes) if inst.drillable[h]]
    best = np.inf
    for owner in itertools.product(range(inst.n_booms), repeat=len(holes)):
        if any(not inst.reach[b, h] for b, h in zip(owner, holes, strict=True)):
            continue
        groups = [[h for h, o in zip(holes, owner, strict=True) if o == b] for b in range(inst.n_booms)]
        for orders in itertools.product(*(itertools.permutations(g) for g in groups)):
            routes = [list(o) for o in orders]
            if not first_ok(inst, routes):
                continue
            best = min(best, makespan_by_hand(inst, routes))
    return best


def first_ok(inst, routes):
    return all(not (s < inst.n_holes and inst.reach[b, s]) or (routes[b] and routes[b][0] == s)
               for b, s in enumerate(inst.starts))


def handed_on(inst: Instance, done, start) -> Instance:
    import dataclasses

    reach = inst.reach.copy()
    reach[:, done] = False
    for b, s in enumerate(start):
        if s < inst.n_holes and s not in done:
            reach[:, s] = False
            reach[b, s] = True
    return dataclasses.replace(inst, reach=reach, start=tuple(start))


def test_timeline_starts_where_each_boom_stands():
    inst = handed_on(line_instance(), done=[0], start=(0, 5))
    tl = simulate(inst, [[1, 2], [4, 3]])
    assert tl.start == [0, 5]
    assert tl.move_start[0][0] == 0 and tl.arrive[0][0] == pytest.approx(1.0)  # 0 -> 1: from hole 0, not park
    assert tl.arrive[1][0] == pytest.approx(1.0)  # R from its park at x = 5 to hole 4


def test_routing_from_where_the_booms_stand_finds_the_brute_force_optimum():
    """Handed on with L standing at hole 3 (not drilled) and hole 0 done: the routing drills hole 3 first
    by L, every other undrilled hole once, and its round is the optimum of a brute force over every
    allocation and order (4 holes, 2 booms), timed by hand; the timeline times the routing's round as
    the hand sum does; the lower bound stays below the optimum."""
    for seed in range(3):
        inst = handed_on(line_instance(seed=seed), done=[0], start=(3, 5))  # L moved to hole 3, not drilled
        r = route(inst, RoundSettings(solution_limit=50))
        assert r.routes[0][0] == 3 and 3 not in r.routes[1]
        assert sorted(r.routes[0] + r.routes[1]) == [1, 2, 3, 4]
        opt = brute_force(inst)
        span = simulate(inst, r.routes).makespan
        assert span == pytest.approx(makespan_by_hand(inst, r.routes), abs=1e-9)
        assert span == pytest.approx(opt, abs=1e-9), f"seed {seed}: routing {span:.3f} s, optimum {opt:.3f} s"
        assert lower_bound(inst) <= opt + 1e-9  # a bound of the handed-on round, from where the booms stand


def test_start_nodes_are_checked():
    with pytest.raises(ConfigError, match="start"):
        line_instance(start=(0,))
    with pytest.raises(ConfigError, match="start"):
        line_instance(start=(0, 9))
