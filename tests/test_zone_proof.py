"""The planner's proof of a round with zones (pipeline.events.zone_proof) and the zones it chooses
(pipeline.events.zone_choice).

- Deadlock: the compiled pass over every state of progress agrees with a second method, a plain
  breadth-first search over sets of states written here, and with the independent checker's level by
  level exploration (round_check.interleavings, no code shared), on random rounds of two and three booms
  with random interlocks and zones (deadlocking ones among them), and finds every deadlock the rule
  meets in the draws.
- Safety: on hand-made rounds with a given conflict table, a conflicting pair left unordered is named,
  a zone over it makes it safe, a boom that stands before a zone next to the other's section is named,
  and a stand the nominal round covered (the other's action between its neighbours) is not.
- The search: on a round where one boom is late at an interlock, the chosen zone cuts the standing,
  keeps the nominal makespan, and its round is proved.
"""

from __future__ import annotations

import importlib
from collections import deque

import numpy as np
import pytest
from test_zones import make_actions, random_interlocks, random_round, random_zones, two_booms

from pipeline.events.actions import Actions, actions_table, interlocks_table
from pipeline.events.draws import DrawSettings, draws, run, summary
from pipeline.events.zone_choice import ZoneSettings, choose_zones, prove, zones_of
from pipeline.events.zone_proof import closure, deadlock, unsafe
from pipeline.events.zones import NO_ZONES, Zones, zones_table

rc_actions = importlib.import_module("round_check.actions")  # the independent checker (scripts/round_check)
rc_interleavings = importlib.import_module("round_check.interleavings")


def brute_force_deadlock(acts: Actions, edges: np.ndarray, zones: Zones) -> bool:
    """A second method: breadth-first search over states ``(per boom: actions done, running or not)``,
    each transition checked action by action from the edges and zones as given."""
    B = len(acts.booms)
    mine = [np.flatnonzero(acts.boom == b).tolist() for b in range(B)]
    preds = {k: [int(u) for u, v in edges if v == k] for k in range(len(acts))}
    sections = [(z, int(f), int(la)) for z, f, la in zip(zones.zone, zones.first, zones.last, strict=True)]

    def done(state, k):  # action k (global) has ended in this state
        b = int(acts.boom[k])
        return mine[b].index(k) < state[b][0]

    def inside(state, b, z):  # boom b is inside zone z: running or between actions of its section
        for zz, f, la in sections:
            if zz == z and acts.boom[f] == b:
                pos = [mine[b].index(f), mine[b].index(la)]
                n_done, running = state[b]
                started = n_done + (1 if running else 0)  # actions started
                return started > pos[0] and n_done <= pos[1]
        return False

    start = tuple((0, False) for _ in range(B))
    seen, todo = {start}, deque([start])
    while todo:
        s = todo.popleft()
        nxt = []
        for b in range(B):
            n_done, running = s[b]
            if running:
                nxt.append(tuple((n_done + 1, False) if i == b else s[i] for i in range(B)))
            elif n_done < len(mine[b]):
                k = mine[b][n_done]
                ok = all(done(s, u) for u in preds[k])
                for z, f, _ in sections:
                    if f == k and any(inside(s, o, z) for o in range(B) if o != b):
                        ok = False
                if ok:
                    nxt.append(tuple((n_done, True) if i == b else s[i] for i in range(B)))
        if not nxt and any(s[b][0] < len(mine[b]) for b in range(B)):
            return True
        for t in nxt:
            if t not in seen:
                seen.add(t)
                todo.append(t)
    return False


def proof_round(seed: int):
    """Two or three booms of one to six holes, up to eight random interlocks and one to three zones: a
    deadlock in about half of them."""
    rng = np.random.default_rng(500 + seed)
    B = 2 + seed % 2
    acts = make_actions([int(x) for x in rng.integers(1, 7, B)], rng)
    return acts, random_interlocks(acts, int(rng.integers(2, 9)), rng), random_zones(acts, int(rng.integers(1, 4)), rng)


ROUNDS = 40


@pytest.mark.parametrize("seed", range(ROUNDS))
def test_the_deadlock_proof_agrees_with_a_breadth_first_search(seed):
    acts, edges, zones = proof_round(seed)
    assert (deadlock(acts, edges, zones) is not None) == brute_force_deadlock(acts, edges, zones)


@pytest.mark.parametrize("seed", range(24))
def test_every_deadlock_the_rule_meets_is_found(seed):
    acts, edges, zones, dur = random_round(seed)
    stuck = deadlock(acts, edges, zones)
    ex = run_rule(acts, edges, zones, dur)
    if ex.deadlocked.any():  # a deadlock the draws meet is one of the interleavings
        assert stuck is not None


@pytest.mark.parametrize("seed", range(ROUNDS))
def test_the_deadlock_proof_agrees_with_the_independent_checkers_exploration(tmp_path, seed):
    acts, edges, zones = proof_round(seed)
    paths = {k: tmp_path / f"r_{k}.csv" for k in ("actions", "interlocks", "zones")}
    actions_table(acts).to_csv(paths["actions"], index=False)
    interlocks_table(acts, edges).to_csv(paths["interlocks"], index=False)
    zones_table(acts, zones).to_csv(paths["zones"], index=False)
    ra = rc_actions.read_actions(paths["actions"], list(acts.booms))
    found = rc_interleavings.explore(ra, rc_actions.read_interlocks(paths["interlocks"], ra),
                                     rc_actions.read_zones(paths["zones"], ra))
    assert found["explored"] and (found["deadlock"] is not None) == (deadlock(acts, edges, zones) is not None)


def run_rule(acts, edges, zones, dur):
    from pipeline.events.rule import _by_events, _execution

    start, end, deadlocked, stuck, zw = _by_events(acts, np.asarray(edges, int).reshape(-1, 2), dur, zones)
    return _execution(acts, start, end, stuck, deadlocked, zw)


def test_the_random_rounds_hold_deadlocks_and_rounds_free_of_them():
    found = [deadlock(*proof_round(s)) is not None for s in range(ROUNDS)]
    assert 10 <= sum(found) <= ROUNDS - 10  # the cross-checks above are not vacuous either way


def test_a_zone_with_an_interlock_into_its_section_deadlocks_whoever_enters():
    zones = Zones(("z", "z"), np.array([1, 6]), np.array([2, 6]))
    acts, _ = two_booms(50.0, 50.0, zones, [(6, 2)])
    stuck = deadlock(acts, np.array([(6, 2)]), zones)
    assert stuck == [2, 6]  # B0 inside, before its move 2, waiting for B1's drill, which cannot enter
    assert deadlock(acts, np.zeros((0, 2), int), zones) is None
    assert deadlock(acts, np.array([(6, 2)]), NO_ZONES) is None
    with pytest.raises(ValueError, match="max_states"):
        deadlock(acts, np.zeros((0, 2), int), zones, max_states=10)


def _two(conflicting):
    """Booms B0 and B1, two holes each (actions 0-4 and 5-9: move, drill, move, drill, move) and a
    conflict table with the given pairs."""
    acts = make_actions([2, 2], np.random.default_rng(1))
    c = np.zeros((len(acts), len(acts)), bool)
    for u, v in conflicting:
        c[u, v] = c[v, u] = True
    return acts, c


def test_a_conflicting_pair_is_safe_ordered_or_in_one_zone_and_named_otherwise():
    acts, c = _two([(2, 7)])  # B0's move 2 against B1's move 7
    assert unsafe(acts, c, closure(acts, np.array([(2, 7)])), NO_ZONES) is None
    said = unsafe(acts, c, closure(acts, np.zeros((0, 2), int)), NO_ZONES)
    assert said is not None and "B0#2" in said and "B1#2" in said
    zone = Zones(("z", "z"), np.array([2, 7]), np.array([2, 7]))
    assert unsafe(acts, c, closure(acts, np.zeros((0, 2), int)), zone) is None


def test_a_boom_standing_before_a_zone_close_to_the_others_section_is_named():
    # B0 drills hole 1 (action 1) where B1's move 7 passes: B0 may stand there, before its zone, while
    # B1 is inside
    acts, c = _two([(2, 7), (1, 7)])
    zone = Zones(("z", "z"), np.array([2, 7]), np.array([2, 7]))
    said = unsafe(acts, c, closure(acts, np.array([(1, 7)])), zone)
    assert said is not None and "standing between B0#1" in said and "B1#2" in said
    # the same stand with B1's move ordered after B0's move 2 as well: B0 never stands there during it
    assert unsafe(acts, c, closure(acts, np.array([(1, 7), (2, 7)])), NO_ZONES) is None


def test_a_stand_around_the_others_action_is_covered_by_the_nominal_round():
    # B0 stands between its drill 1 and move 2 while B1's move 7 runs (1 -> 7 -> 2): in every execution,
    # as in the nominal round that was scanned clear
    acts, c = _two([(1, 7), (2, 7)])
    assert unsafe(acts, c, closure(acts, np.array([(1, 7), (7, 2)])), NO_ZONES) is None
    assert unsafe(acts, c, closure(acts, np.array([(1, 7)])), NO_ZONES) is not None


def test_the_search_zones_a_late_boom_out_of_standing_and_proves_it():
    # two booms of six holes, each move 10 s, drills 60 s; B1's drill 3 conflicts with B0's drill 3 and
    # their moves around them, ordered B0 first: B1 stands whenever B0 is late
    acts = make_actions([6, 6], np.random.default_rng(2))
    n = len(acts) // 2
    acts = Actions(acts.booms, acts.hole_ids, acts.boom, acts.index, acts.kind, acts.hole, acts.src, acts.dst,
                   np.zeros(len(acts)), np.where(acts.is_drill, 60.0, 10.0))
    pairs = [(a, n + b) for a in (6, 7, 8) for b in (6, 7, 8)]
    c = np.zeros((len(acts), len(acts)), bool)
    for u, v in pairs:
        c[u, v] = c[v, u] = True
    edges = np.array(pairs)  # B0 first, every pair
    drill_s = np.full(len(acts.hole_ids), 60.0)
    d = draws(acts, DrawSettings(count=300, seed=1))
    before = summary(run(acts, edges, drill_s, d), 0.0, d)["random"]["standing_share_p95"]
    choice = choose_zones(acts, edges, np.zeros((0, 2), int), c, drill_s, d.factors[:300], ZoneSettings())
    assert len(choice.zones) == 2 and choice.stats["zones"] == 1
    z = choice.zones
    assert z.first[0] <= 6 and z.last[0] >= 8 and z.first[1] <= n + 6 and z.last[1] >= n + 8  # the whole contest
    assert prove(acts, choice.edges, z, c) is None
    ex = run(acts, choice.edges, drill_s, d, z)
    after = summary(ex, 0.0, d)["random"]["standing_share_p95"]
    assert not ex.deadlocked.any() and after < before - 0.001
    # nominal makespan kept within the slack
    from pipeline.events.rule import execute

    assert execute(acts, choice.edges, drill_s, z).makespan[0] <= 1.005 * execute(acts, edges, drill_s).makespan[0]
    assert zones_of([]) is NO_ZONES


def test_zones_off_chooses_none():
    acts, c = _two([(2, 7)])
    choice = choose_zones(acts, np.array([(2, 7)]), np.zeros((0, 2), int), c, np.full(4, 50.0),
                          np.ones((5, 4)), ZoneSettings(choose=False))
    assert len(choice.zones) == 0 and choice.edges.tolist() == [[2, 7]]
