"""Zones (docs/reference.md, section 9): the file read and written, and the execution rule with zones,
checked against a second method and against the independent checker's own rule.

- Without zones, the rule by events gives the times of the pass over a fixed order (two methods).
- With zones, the rule gives the start and end of every action, and the same deadlocks, as the
  checker's (:func:`round_check.execute.execute_zones`, which shares no code with it: draw by draw,
  booms in a loop), on random rounds of two and three booms with random interlocks and zones.
- By hand: whichever boom arrives first goes first, the rig's first on a tie; a zone with an interlock
  that deadlocks only in the draws where the wrong boom gets in first.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.events import rule
from pipeline.events.actions import Actions, actions_table, interlocks_table, read_actions
from pipeline.events.draws import DrawSettings, draws, run, summary
from pipeline.events.graph import find_cycle
from pipeline.events.zones import NO_ZONES, ZONE_COLUMNS, Zones, read_zones, zones_table

rc_actions = importlib.import_module("round_check.actions")  # the checker's own rule (scripts/round_check)
rc_execute = importlib.import_module("round_check.execute")


def make_actions(holes_per_boom: list[int], rng, same: bool = False) -> Actions:
    """Booms B0, B1, ... each with a route of its own holes: move, drill, move, ..., drill, move to park;
    planned times one after another with random durations (whole 5 s, so that booms can be ready at one
    instant); ``same``: every boom with the same durations."""
    cols = {k: [] for k in ("boom", "index", "kind", "hole", "src", "dst", "t_start", "t_end")}
    H = sum(holes_per_boom)
    h0 = 0
    state = rng.bit_generator.state
    for b, n in enumerate(holes_per_boom):
        if same:
            rng.bit_generator.state = state
        route = list(range(h0, h0 + n))
        h0 += n
        nodes = [H, *route, H]
        t, i = 0.0, 0
        for j in range(n + 1):
            for kind, hole, src, dst in (("move", -1, nodes[j], nodes[j + 1]),
                                         *((("drill", route[j], route[j], route[j]),) if j < n else ())):
                d = float(5 * rng.integers(1, 6) if kind == "move" else 5 * rng.integers(8, 24))
                for k, v in zip(cols, (b, i, kind, hole, src, dst, t, t + d), strict=True):
                    cols[k].append(v)
                t, i = t + d, i + 1
    arr = {k: np.asarray(v, dtype=float if k.startswith("t_") else (str if k == "kind" else int))
           for k, v in cols.items()}
    return Actions(tuple(f"B{b}" for b in range(len(holes_per_boom))), tuple(f"h{h}" for h in range(H)), **arr)


def random_interlocks(acts: Actions, n: int, rng) -> np.ndarray:
    """Up to ``n`` interlocks between actions of different booms, kept acyclic with the sequences."""
    seq = acts.sequence_edges()
    out: list[tuple[int, int]] = []
    for _ in range(4 * n):
        u, v = rng.integers(0, len(acts), 2)
        if acts.boom[u] == acts.boom[v] or len(out) >= n:
            continue
        trial = np.array([*out, (u, v)], int)
        if find_cycle(len(acts), np.concatenate([seq, trial])) is None:
            out.append((int(u), int(v)))
    return np.array(out, int).reshape(-1, 2)


def random_zones(acts: Actions, n: int, rng) -> Zones:
    """``n`` zones over two random booms each (or all three, every other zone of a three-boom rig), one
    section of one to four actions per boom, at about the same place in the booms' sequences (where
    they contend)."""
    B = len(acts.booms)
    names, first, last = [], [], []
    for z in range(n):
        at = rng.uniform(0, 1)
        for b in rng.choice(B, size=3 if B == 3 and z % 2 == 0 else 2, replace=False):
            mine = np.flatnonzero(acts.boom == b)
            f = int(np.clip(round(at * (len(mine) - 1)) + rng.integers(-1, 2), 0, len(mine) - 1))
            la = min(len(mine) - 1, f + int(rng.integers(0, 4)))
            names.append(f"z{z}")
            first.append(int(mine[f]))
            last.append(int(mine[la]))
    return Zones(tuple(names), np.array(first), np.array(last))


def checker_rule(tmp_path, acts: Actions, edges: np.ndarray, zones: Zones, dur: np.ndarray):
    """The independent checker's rule on the same round, written as the files it reads."""
    paths = {k: tmp_path / f"r_{k}.csv" for k in ("actions", "interlocks", "zones")}
    actions_table(acts).to_csv(paths["actions"], index=False)
    interlocks_table(acts, edges).to_csv(paths["interlocks"], index=False)
    zones_table(acts, zones).to_csv(paths["zones"], index=False)
    ra = rc_actions.read_actions(paths["actions"], list(acts.booms))
    locks = rc_actions.read_interlocks(paths["interlocks"], ra)
    rz = rc_actions.read_zones(paths["zones"], ra)
    g = rc_execute.graph(ra, locks)
    return rc_execute.execute_zones(ra, g, rz, dur)


def random_round(seed: int):
    """Two or three booms, random interlocks and zones, and 40 draws of action durations: the first five
    with every drill at its planned duration (booms with the same durations then reach a zone at one
    instant), the rest 0.7-1.5x."""
    rng = np.random.default_rng(100 + seed)
    B = 2 + seed % 2
    same = seed % 3 == 0
    acts = make_actions([int(x) for x in (np.full(B, rng.integers(2, 7)) if same else rng.integers(1, 7, B))], rng,
                        same)
    edges = random_interlocks(acts, 0 if same else int(rng.integers(0, 6)), rng)
    zones = random_zones(acts, int(rng.integers(1, 4)), rng)
    dur = np.broadcast_to(acts.duration, (40, len(acts))).copy()
    drills = acts.is_drill
    dur[5:, drills] *= rng.uniform(0.7, 1.5, (35, int(drills.sum())))
    return acts, edges, zones, dur


@pytest.mark.parametrize("seed", range(6))
def test_without_zones_the_rule_by_events_is_the_pass_in_order(seed):
    rng = np.random.default_rng(seed)
    acts = make_actions([int(x) for x in rng.integers(0, 7, 3)], rng)
    edges = random_interlocks(acts, 12, rng)
    dur = rule.durations(acts, acts.duration[acts.is_drill][np.argsort(acts.hole[acts.is_drill])][None, :]
                         * rng.uniform(0.7, 1.5, (50, len(acts.hole_ids))))
    ordered = rule._in_order(acts, edges, dur)
    start, end, deadlocked, stuck, zone_wait = rule._by_events(acts, edges, dur, NO_ZONES)
    assert not deadlocked.any() and stuck is None and ordered.deadlock is None and not zone_wait.any()
    np.testing.assert_allclose(start, ordered.start, rtol=0, atol=1e-9)
    np.testing.assert_allclose(end, ordered.end, rtol=0, atol=1e-9)


SEEDS = range(24)


@pytest.mark.parametrize("seed", SEEDS)
def test_with_zones_the_rule_is_the_independent_checkers(tmp_path, seed):
    acts, edges, zones, dur = random_round(seed)
    ex = rule.execute(acts, edges, _drill_matrix(acts, dur), zones)
    c_start, c_end, c_stuck = checker_rule(tmp_path, acts, edges, zones, dur)
    c_dead = np.array([s is not None for s in c_stuck])
    assert (ex.deadlocked == c_dead).all()
    ok = ~c_dead
    np.testing.assert_allclose(ex.start[ok], c_start[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(ex.end[ok], c_end[ok], rtol=0, atol=1e-9)
    for d in np.flatnonzero(c_dead):  # what started before the deadlock started at the same times
        began = np.isfinite(c_start[d])
        assert (np.isfinite(ex.start[d]) == began).all()
        np.testing.assert_allclose(ex.start[d, began], c_start[d, began], rtol=0, atol=1e-9)


def _drill_matrix(acts: Actions, dur: np.ndarray) -> np.ndarray:
    """The (D, H) drilling durations that give the action durations ``dur``; its moves are put back to
    their planned durations, which the rule keeps."""
    out = np.ones((dur.shape[0], len(acts.hole_ids)))
    drills = np.flatnonzero(acts.is_drill)
    out[:, acts.hole[drills]] = dur[:, drills]
    moves = ~acts.is_drill
    dur[:, moves] = acts.duration[moves]
    return out


def test_the_random_rounds_meet_deadlocks_and_ties():
    """The cross-check above is worth something only if its rounds hold zones that decide, ties and
    deadlocks: counted over the same seeds."""
    dead = ties = swapped = three = 0
    for seed in SEEDS:
        acts, edges, zones, dur = random_round(seed)
        ex = rule.execute(acts, edges, _drill_matrix(acts, dur), zones)
        dead += int(ex.deadlocked.sum())
        entries = np.asarray(zones.first)
        prev = acts.previous[entries]
        ready = np.where(prev >= 0, ex.end[:, np.clip(prev, 0, None)], 0.0)  # when each could go in
        zone = np.array(zones.zone)
        for z in zones.names:
            r = ready[~ex.deadlocked][:, zone == z]
            ties += int((np.diff(np.sort(r, 1), axis=1) < 1e-9).any(1).sum())
            three += r.shape[1] == 3
        swapped += len({tuple(np.argsort(row)) for row in ex.start[~ex.deadlocked][:, entries]}) > 1
    assert dead > 0 and ties > 0 and swapped >= 6 and three > 0, (dead, ties, swapped, three)


def two_booms(drill_a: float, drill_b: float, zones: Zones, edges=()):
    """Booms B0 and B1, two holes each (actions move, drill, move, drill, move); every move 10 s."""
    acts = make_actions([2, 2], np.random.default_rng(0))
    acts = Actions(acts.booms, acts.hole_ids, acts.boom, acts.index, acts.kind, acts.hole, acts.src, acts.dst,
                   np.zeros(len(acts)), np.where(acts.is_drill, 50.0, 10.0))
    drill = np.array([[drill_a, 50.0, drill_b, 50.0]])
    return acts, rule.execute(acts, np.array(edges, int).reshape(-1, 2), drill, zones)


# each boom's second drill (action 3) in one zone
SECOND_DRILLS = Zones(("z", "z"), np.array([3, 8]), np.array([3, 8]))


def test_whichever_boom_arrives_first_drills_first_in_the_zone():
    acts, ex = two_booms(80.0, 50.0, SECOND_DRILLS)  # B1 at its second hole first (t = 70 against 100)
    assert ex.start[0, 8] == 70.0 and ex.start[0, 3] == 120.0  # B0 stands until B1's drill ends
    assert ex.standing[0].tolist() == [20.0, 0.0]
    acts, ex = two_booms(50.0, 80.0, SECOND_DRILLS)  # the other way round: B0 first, B1 stands
    assert ex.start[0, 3] == 70.0 and ex.start[0, 8] == 120.0
    assert ex.standing[0].tolist() == [0.0, 20.0]
    acts, ex = two_booms(50.0, 50.0, SECOND_DRILLS)  # both at t = 70: the rig's first boom goes in
    assert ex.start[0, 3] == 70.0 and ex.start[0, 8] == 120.0
    none = rule.execute(acts, np.zeros((0, 2), int), np.array([[50.0, 50.0, 50.0, 50.0]]), NO_ZONES)
    assert none.start[0, 3] == none.start[0, 8] == 70.0  # without the zone they drill at once


def test_a_zone_and_an_interlock_deadlock_only_when_the_wrong_boom_gets_in_first():
    # one zone over B0's drill 1 .. move 2 and B1's drill 1; B0's move 2 waits (interlock) for B1's drill 1
    zones = Zones(("z", "z"), np.array([1, 6]), np.array([2, 6]))
    edges = [(6, 2)]
    _, early_a = two_booms(50.0, 50.0, zones, edges)  # B0 gets in first at t = 10 (a tie: the rig's first)
    assert early_a.deadlocked.tolist() == [True] and early_a.deadlock == [2, 6]
    acts = make_actions([2, 2], np.random.default_rng(0))
    acts = Actions(acts.booms, acts.hole_ids, acts.boom, acts.index, acts.kind, acts.hole, acts.src, acts.dst,
                   np.zeros(len(acts)), np.where(acts.is_drill, 50.0, np.where(acts.boom == 0, 20.0, 10.0)))
    ex = rule.execute(acts, np.array(edges), np.full((1, 4), 50.0), zones)  # B1 first (t = 10 against 20)
    assert not ex.deadlocked.any() and ex.start[0, 1] == 60.0  # B0 enters once B1's drill has ended
    d = draws(acts, DrawSettings(count=30, seed=3))
    s = summary(run(acts, np.array(edges), np.full(4, 50.0), d, zones), 100.0, d)
    assert s["deadlocks"] == 0


def test_the_zones_file_round_trips_and_a_header_alone_is_no_zone(tmp_path):
    acts = make_actions([2, 3], np.random.default_rng(1))
    zones = Zones(("b", "b", "a", "a"), np.array([1, 6, 3, 9]), np.array([2, 8, 3, 10]))
    (tmp_path / "actions.csv").write_text(actions_table(acts).to_csv(index=False))
    table = read_actions(tmp_path / "actions.csv")
    zones_table(acts, zones).to_csv(tmp_path / "zones.csv", index=False)
    back = read_zones(tmp_path / "zones.csv", table, acts)
    key = sorted(zip(back.zone, back.first.tolist(), back.last.tolist(), strict=True))
    assert key == sorted(zip(zones.zone, zones.first.tolist(), zones.last.tolist(), strict=True))
    zones_table(acts, NO_ZONES).to_csv(tmp_path / "none.csv", index=False)
    assert (tmp_path / "none.csv").read_text().strip() == ",".join(ZONE_COLUMNS)
    assert len(read_zones(tmp_path / "none.csv", table, acts)) == 0


@pytest.mark.parametrize("rows, said", [
    ("zone,boom,first_action\nz,B0,1\n", "missing column(s) ['last_action']"),
    ("zone,boom,first_action,last_action\n,B0,1,1\nz,B1,1,1\n", "row 2: empty zone"),
    ("zone,boom,first_action,last_action\nz,B7,1,1\nz,B1,1,1\n", "row 2: boom = 'B7': no such boom"),
    ("zone,boom,first_action,last_action\nz,B0,1,1\nz,B1,1,9\n", "row 3: last_action = 9: boom 'B1' has no action 9"),
    ("zone,boom,first_action,last_action\nz,B0,3,1\nz,B1,1,1\n", "row 2: last_action = 1 is before first_action = 3"),
    ("zone,boom,first_action,last_action\nz,B0,1,1\nz,B1,1,1\nz,B0,3,3\n", "row 4: boom 'B0' has a second section"),
    ("zone,boom,first_action,last_action\nz,B0,1,1\n", "row 2: zone 'z' has one boom only"),
    ("zone,boom,first_action,last_action\nz,B0,x,1\nz,B1,1,1\n", "row 2: first_action = 'x'"),
])
def test_a_bad_zones_file_is_refused_naming_the_row(tmp_path, rows, said):
    acts = make_actions([2, 2], np.random.default_rng(2))
    (tmp_path / "actions.csv").write_text(actions_table(acts).to_csv(index=False))
    (tmp_path / "zones.csv").write_text(rows)
    with pytest.raises(InputError) as e:
        read_zones(tmp_path / "zones.csv", read_actions(tmp_path / "actions.csv"), acts)
    assert said in str(e.value) and "zones.csv" in str(e.value)


def test_zones_given_to_the_rule_are_checked():
    acts = make_actions([2, 2], np.random.default_rng(2))
    with pytest.raises(InputError, match="not a range of one boom's actions"):
        rule.execute(acts, np.zeros((0, 2), int), np.full(4, 50.0), Zones(("z", "z"), np.array([3, 4]),
                                                                           np.array([5, 5])))
    with pytest.raises(InputError, match="one boom only"):
        rule.execute(acts, np.zeros((0, 2), int), np.full(4, 50.0), Zones(("z",), np.array([1]), np.array([1])))


def test_standing_is_split_by_cause_and_the_summary_gives_each():
    """B0 waits 20 s at its second hole: for the zone B1 is inside, or for an interlock on B1's drill (an
    order); the boom done first stands at park until the round ends (nothing left to do)."""
    _, by_zone = two_booms(80.0, 50.0, SECOND_DRILLS)
    assert by_zone.standing_zone[0].tolist() == [20.0, 0.0] and by_zone.standing_order[0].tolist() == [0.0, 0.0]
    assert by_zone.makespan[0] == 180.0 and by_zone.idle_after[0].tolist() == [0.0, 50.0]
    _, by_order = two_booms(80.0, 50.0, NO_ZONES, [(8, 3)])  # B0's second drill after B1's
    assert by_order.standing_order[0].tolist() == [20.0, 0.0] and by_order.standing_zone[0].tolist() == [0.0, 0.0]
    acts = make_actions([2, 2], np.random.default_rng(0))
    d = draws(acts, DrawSettings(count=40, seed=1))
    ex_zoned = run(acts, np.zeros((0, 2), int), np.full(4, 60.0), d, SECOND_DRILLS)
    assert (ex_zoned.standing_zone[:, 0] > 0).any() and (ex_zoned.standing_zone[:, 1] > 0).any()  # either first
    zoned = summary(ex_zoned, 100.0, d)["random"]
    ordered = summary(run(acts, np.array([(8, 3)]), np.full(4, 60.0), d), 100.0, d)["random"]
    assert zoned["order_share_p95"] == 0 < zoned["zone_share_p50"] <= zoned["zone_share_p95"]
    assert ordered["zone_share_p95"] == 0 < ordered["order_share_p50"] <= ordered["order_share_p95"]
    for s in (zoned, ordered):  # one cause each here, so it is all of the standing
        assert s["standing_share_p95"] == pytest.approx(max(s["order_share_p95"], s["zone_share_p95"]))
        assert 0 < s["idle_after_share_p50"] <= s["idle_after_share_p95"] < 1
