"""Executing a round by events (docs/reference.md section 8): actions, certified sweep conflicts, robust
interlocks, the execution rule, Monte Carlo draws, and the actions and interlocks files.

The round is a small real twin round (jumbo8 joints by forward kinematics, tests/fk_rounds.py) whose
two middle holes conflict; its timeline is the conflict loop's (``resolve``) on fixed routes."""

import math

import numpy as np
import pytest
import torch
from fk_rounds import boom_joints

from pipeline.assembly.rig import load_rig
from pipeline.core.config import load_group_file
from pipeline.core.errors import ConfigError, InputError
from pipeline.events.actions import (
    Actions,
    actions_of,
    actions_table,
    interlocks_table,
    read_actions,
    read_interlocks,
)
from pipeline.events.conflicts import conflicts
from pipeline.events.draws import DrawSettings, draws, parse_draws, run, summary
from pipeline.events.graph import find_cycle, reduce_edges
from pipeline.events.interlocks import robust_round
from pipeline.events.rule import execute, realised
from pipeline.geometry.boom_pair import BoomPair
from pipeline.motion.path import travel
from pipeline.motion.timing import motion_from_config, profile
from pipeline.round.rig_problem import kinematic_round
from pipeline.round.settings import RoundSettings
from pipeline.round.tables import trajectory_table
from pipeline.round.timeline import resolve, scan

D = torch.float64
r = math.radians
MID_L = [r(3), 0.0, 3.5, 0.0, 0.0, r(-3), 0.0, 2.5]  # L's feed on its inner side: collar near y = +0.2
MID_R = [r(-3), 0.0, 3.5, 0.0, 0.0, r(3), r(180), 2.5]  # R's: near y = -0.2; the two conflict


@pytest.fixture(scope="module")
def twin(safety):
    return load_rig("twin", safety.tunnel, safety.distances, safety.points_per_capsule)


@pytest.fixture(scope="module")
def round_(twin, jumbo8):
    """Holes 0 (L's middle), 1 (R's middle), then 4 of L's and 4 of R's; L drills 0, 2..5, R 1, 6..9."""
    motion = motion_from_config(load_group_file("motion", "jumbo8"), jumbo8)
    qL = torch.cat([torch.tensor([MID_L], dtype=D), boom_joints(4, 0, 180)])
    qR = torch.cat([torch.tensor([MID_R], dtype=D), boom_joints(4, 1, 0)])
    nan = torch.full((5, 8), math.nan, dtype=D)
    order = [0, 5, 1, 2, 3, 4, 6, 7, 8, 9]
    jL, jR = torch.cat([qL, nan])[order], torch.cat([nan, qR])[order]
    reach = np.zeros((2, 10), bool)
    reach[0, :5], reach[1, 5:] = True, True
    reach = reach[:, order]
    inst, oracle = kinematic_round(twin, [f"h{k:02d}" for k in range(10)], [jL, jR], reach, np.full(10, 4.0),
                                   [motion, motion], settings=RoundSettings())
    routes = [np.flatnonzero(inst.reach[b]).tolist() for b in range(2)]
    tl = resolve(inst, routes, oracle)
    assert tl.conflicts_left == 0 and not tl.sequential
    return inst, oracle, tl, robust_round(inst, tl, oracle)


# ---------------------------------------------------------------- actions
def test_actions_run_from_park_to_park_with_the_planned_times(round_):
    inst, _, tl, _ = round_
    acts = actions_of(inst, tl)
    for b, route in enumerate(tl.routes):
        mine = acts.boom == b
        assert acts.index[mine].tolist() == list(range(2 * len(route) + 1))
        assert acts.kind[mine].tolist() == ["move", "drill"] * len(route) + ["move"]
        assert acts.hole[mine & acts.is_drill].tolist() == route
        moves = mine & ~acts.is_drill
        assert np.array_equal(acts.t_start[moves], tl.move_start[b]) and np.array_equal(acts.t_end[moves], tl.arrive[b])
        drills = mine & acts.is_drill
        assert np.array_equal(acts.t_start[drills], tl.arrive[b][:-1])
        assert np.allclose(acts.duration[drills], 10 + 4.0 / 2.5 * 60 + 4.0, rtol=0, atol=1e-9)  # section 7 by hand
        assert acts.src[moves][0] == inst.n_holes and acts.dst[moves][-1] == inst.n_holes  # park to park


def _hand_actions():
    """Boom A: move, drill h0, move; boom B: move, drill h1, move (planned times 0..)."""
    boom = np.array([0, 0, 0, 1, 1, 1])
    kind = np.array(["move", "drill", "move"] * 2)
    return Actions(("A", "B"), ("h0", "h1"), boom, np.array([0, 1, 2] * 2), kind, np.array([-1, 0, -1, -1, 1, -1]),
                   np.array([2, 0, 0, 2, 1, 1]), np.array([0, 0, 2, 1, 1, 2]),
                   np.array([0.0, 2, 12, 0, 3, 23]), np.array([2.0, 12, 15, 3, 23, 24]))


def test_execution_rule_by_hand():
    """B's drill waits for A's drill: B stands from 3 to 12; with A's drill at 20 s, to 22."""
    acts = _hand_actions()
    ex = execute(acts, np.array([[1, 4]]), np.array([[10.0, 20.0], [20.0, 20.0]]))
    assert ex.start[0].tolist() == [0, 2, 12, 0, 12, 32] and ex.end[0].tolist() == [2, 12, 15, 3, 32, 33]
    assert ex.start[1].tolist() == [0, 2, 22, 0, 22, 42] and ex.makespan.tolist() == [33, 43]
    assert ex.standing.tolist() == [[0, 9], [0, 19]] and ex.deadlock is None


def test_a_cycle_in_the_interlocks_is_reported_as_a_deadlock():
    acts = _hand_actions()
    ex = execute(acts, np.array([[1, 4], [4, 1]]), np.array([10.0, 20.0]))
    assert ex.deadlock is not None and set(ex.deadlock) == {1, 4}
    assert np.isinf(ex.end[0, [1, 2, 4, 5]]).all() and np.isinf(ex.makespan).all()
    assert find_cycle(6, np.array([[0, 1], [1, 2], [2, 0]])) is not None
    # a reduction keeps what the others do not imply: 0 -> 2 follows from 0 -> 1 -> 2 (the sequence)
    assert reduce_edges(4, np.array([[0, 1], [1, 2]]), np.array([[0, 2], [2, 3], [0, 3]])).tolist() == [[2, 3]]


# ---------------------------------------------------------------- sweeps
def test_sweep_conflicts_agree_with_a_dense_brute_force(round_, twin):
    """Every pair of actions of the two booms small enough to brute-force (at most 0.1 M configuration
    pairs: every drill against every action), sampled
    independently at 3 mm of point travel and measured with the rig's own clearance: a pair below the
    margin is always a conflict, a pair not flagged is above it, and the certified lower bound never
    exceeds the dense minimum."""
    inst, oracle, tl, _ = round_
    acts = actions_of(inst, tl)
    conf = conflicts(acts, oracle)
    listed = {(int(i), int(j)): k for k, (i, j) in enumerate(conf.pairs)}

    def dense(k):
        b, q = int(acts.boom[k]), oracle.joints[int(acts.boom[k])]
        if acts.is_drill[k]:
            return q[int(acts.hole[k])][None]
        p = profile(q[int(acts.src[k])], q[int(acts.dst[k])], oracle.limits[b])
        n = max(1, math.ceil(float(travel(p.step, oracle.levers[b])) / 0.003))
        return p.start + torch.linspace(0, 1, n + 1, dtype=D)[:, None] * p.step

    seen, checked = set(), 0
    samples = {k: dense(k) for k in range(len(acts))}
    pair = twin.pair(0, 1)
    for i in np.flatnonzero(acts.boom == 0):
        for j in np.flatnonzero(acts.boom == 1):
            qa, qb = samples[i], samples[j]
            if len(qa) * len(qb) > 100_000:
                continue
            step = max(1, 50_000 // len(qb))  # configuration pairs per call: memory stays small
            with torch.inference_mode():  # torch's BoomPair, not the compiled kernel the sweeps use
                m = min(float(pair.clearance(twin.booms[0].frames(qa[s:s + step, None]),
                                             twin.booms[1].frames(qb[None])).min())
                        for s in range(0, len(qa), step))
            k = listed.get((int(i), int(j)))
            flagged = k is not None and bool(conf.conflict[k])
            if m < conf.margin:
                assert flagged, (acts.name(i), acts.name(j), m)
            if not flagged:
                assert m >= conf.margin
            if k is not None:
                assert conf.lower[k] <= m + 1e-9
            seen.add(flagged)
            checked += 1
    assert seen == {True, False} and checked >= 80  # both answers seen, every pair with a drill compared


def test_swept_pairs_known_from_an_earlier_round_give_the_same_conflicts(round_):
    """The oracle keeps each measured pair of sweeps (a round handed on shares most of its actions with
    the planned one): looked up, they give exactly what measuring them again gives, and cost nothing."""
    inst, oracle, tl, _ = round_
    acts = actions_of(inst, tl)
    saved = dict(oracle.sweep_pairs)
    try:
        oracle.sweep_pairs.clear()
        fresh = conflicts(acts, oracle)
        assert fresh.evaluations > 0 and len(oracle.sweep_pairs) == len(fresh.pairs)
        again = conflicts(acts, oracle)
        assert again.evaluations == 0
        np.testing.assert_array_equal(again.pairs, fresh.pairs)
        np.testing.assert_array_equal(again.least, fresh.least)
        np.testing.assert_array_equal(again.conflict, fresh.conflict)
        # a pair's result is keyed by what fixes its sweeps: a wrong cached value would be used, so
        # planting one shows the lookup is real (and why the move file is refused on other settings)
        key = next(iter(oracle.sweep_pairs))
        oracle.sweep_pairs[key] = (-1.0, -1.0)
        planted = conflicts(acts, oracle)
        assert planted.conflict.sum() >= fresh.conflict.sum() and (planted.least == -1.0).sum() == 1
    finally:
        oracle.sweep_pairs.clear()
        oracle.sweep_pairs.update(saved)


# ---------------------------------------------------------------- interlocks and the execute stage
def test_interlocks_order_the_middle_holes_and_the_nominal_round_is_clear(round_):
    inst, oracle, tl, rr = round_
    assert rr.problem is None and rr.stats["conflicts_left"] == 0
    assert 0 < rr.stats["interlocks"] <= rr.stats["interlocks_before_reduction"] <= rr.stats["conflicting_pairs"]
    assert scan(rr.timeline, oracle) is None
    acts = rr.actions
    d0, d1 = acts.of(0, 1), acts.of(1, 1)  # the two middle drills
    assert acts.hole[[d0, d1]].tolist() == [0, 1]
    assert acts.t_end[d0] <= acts.t_start[d1] or acts.t_end[d1] <= acts.t_start[d0]
    assert rr.stats["nominal_makespan_s"] >= tl.makespan * 0.9  # a re-timing, not another round


def test_the_execution_rule_with_model_durations_reproduces_the_nominal_round(round_):
    inst, oracle, _, rr = round_
    ex = execute(rr.actions, rr.interlocks, inst.drill_s)
    assert np.array_equal(ex.start[0], rr.actions.t_start) and np.array_equal(ex.end[0], rr.actions.t_end)
    assert abs(float(ex.makespan[0]) - rr.timeline.makespan) < 1.0
    inst_r, tl_r = realised(inst, rr.actions, ex)
    names = oracle.rig.booms[0].boom.joint_names
    a, b = trajectory_table(inst_r, tl_r, oracle, names), trajectory_table(inst, rr.timeline, oracle, names)
    assert a.equals(b)  # the same trajectory file


def _breaks(inst, oracle, acts, edges, factors):
    ex = execute(acts, edges, factors * inst.drill_s[None])
    bad = []
    for d in range(len(factors)):
        _, tl = realised(inst, acts, ex, d)
        if scan(tl, oracle) is not None:
            bad.append(d)
    return bad


def test_no_draw_breaks_d_boom_with_all_interlocks(round_):
    inst, oracle, _, rr = round_
    d = draws(rr.actions, DrawSettings(count=100, seed=3))
    assert len(d.labels) == 100 + 10 + 2
    assert _breaks(inst, oracle, rr.actions, rr.interlocks, d.factors) == []
    s = summary(run(rr.actions, rr.interlocks, inst.drill_s, d), rr.timeline.makespan, d)
    assert s["deadlocks"] == 0 and s["random"]["draws"] == 100
    assert 0.7 <= s["random"]["makespan_ratio_p50"] <= s["random"]["makespan_ratio_p95"] <= 1.5 + 1e-9


def _dense_least(inst, oracle, tl, twin):
    """Boom-boom distance (m) of a trajectory table at 5 ms, by linear interpolation, from BoomPair."""
    names = oracle.rig.booms[0].boom.joint_names
    traj = trajectory_table(inst, tl, oracle, names)
    t = np.arange(0.0, tl.makespan, 0.005)
    frames = []
    for b, name in enumerate(inst.booms):
        rows = traj[traj["boom"] == name]
        q = np.stack([np.interp(t, rows["t"], rows[n]) for n in names], -1)
        with torch.inference_mode():
            frames.append(twin.booms[b].frames(torch.as_tensor(q)))
    pair = BoomPair(twin.booms[0].boom, twin.booms[1].boom, twin.d_boom)
    with torch.inference_mode():
        return min(float(pair.distances(frames[0][s:s + 20000], frames[1][s:s + 20000]).amin())
                   for s in range(0, len(t), 20000))


def test_deleting_a_needed_interlock_lets_some_draw_break_d_boom(round_, twin):
    inst, oracle, _, rr = round_
    d = draws(rr.actions, DrawSettings(count=10, seed=1))
    found = []
    for k in range(len(rr.interlocks)):
        fewer = np.delete(rr.interlocks, k, axis=0)
        bad = _breaks(inst, oracle, rr.actions, fewer, d.factors)
        if bad:
            found.append((k, bad[0]))
    assert found, "no interlock is needed: they would be decoration"
    k, draw = found[0]
    ex = execute(rr.actions, np.delete(rr.interlocks, k, axis=0), d.factors * inst.drill_s[None])
    inst_r, tl_r = realised(inst, rr.actions, ex, draw)
    assert _dense_least(inst_r, oracle, tl_r, twin) < twin.d_boom  # really below d_boom, not only the margin


# ---------------------------------------------------------------- files
def test_actions_and_interlocks_files_read_back(round_, tmp_path):
    _, _, _, rr = round_
    a, i = tmp_path / "r_actions.csv", tmp_path / "r_interlocks.csv"
    actions_table(rr.actions).to_csv(a, index=False)
    interlocks_table(rr.actions, rr.interlocks).to_csv(i, index=False)
    table = read_actions(a)
    assert np.allclose(table["t_start"], rr.actions.t_start, rtol=0, atol=1e-9)
    edges = read_interlocks(i, table, a)
    assert sorted(map(tuple, edges.tolist())) == sorted(map(tuple, rr.interlocks.tolist()))


def _write(path, text):
    path.write_text(text)
    return path


ACTIONS = ("boom,action,kind,hole_id,t_start,t_end\nA,0,move,,0,2\nA,1,drill,h0,2,12\nA,2,move,,12,15\n"
           "B,0,move,,0,3\nB,1,drill,h1,3,23\nB,2,move,,23,24\n")


@pytest.mark.parametrize("text, message", [
    ("boom,action,kind,t_start,t_end\nA,0,move,0,1\n", "missing column(s) ['hole_id']"),
    (ACTIONS.replace("A,2,move", "A,3,move"), "row 4: boom 'A' action 3 follows action 1"),
    (ACTIONS.replace("A,1,drill,h0", "A,1,drill,"), "row 3: a drill needs a hole_id"),
    (ACTIONS.replace("B,2,move,,23,24", "B,2,move,,23,x"), "row 7: t_end = 'x'"),
    (ACTIONS.replace("A,1,drill", "A,1,jump"), "row 3: kind = 'jump'"),
])
def test_a_bad_actions_file_names_the_file_and_the_row(tmp_path, text, message):
    path = _write(tmp_path / "x_actions.csv", text)
    with pytest.raises(InputError) as e:
        read_actions(path)
    assert str(path) in str(e.value) and message in str(e.value)


@pytest.mark.parametrize("text, message", [
    ("boom,action,after_boom\nB,1,A\n", "missing column(s) ['after_action']"),
    ("boom,action,after_boom,after_action\nB,1,A,1\nB,1,C,0\n", "row 3: after_boom = 'C': no such boom"),
    ("boom,action,after_boom,after_action\nB,7,A,1\n", "row 2: boom 'B' has no action 7"),
    ("boom,action,after_boom,after_action\nB,1,A,1\nA,1,B,2\n", "form a cycle"),
])
def test_a_bad_interlocks_file_names_the_file_and_the_row(tmp_path, text, message):
    actions = read_actions(_write(tmp_path / "x_actions.csv", ACTIONS))
    path = _write(tmp_path / "x_interlocks.csv", text)
    with pytest.raises(InputError) as e:
        read_interlocks(path, actions)
    assert str(path) in str(e.value) and message in str(e.value)
    if "cycle" in message:
        assert "row 3" in str(e.value) or "row 2" in str(e.value)


def test_draw_settings_are_checked():
    assert parse_draws({"count": 5}).count == 5
    with pytest.raises(ConfigError, match="draws.high"):
        parse_draws({"low": 1.2, "high": 1.0})
    with pytest.raises(ConfigError, match="draws.draw"):
        parse_draws({"draw": 5})


def test_the_round_made_robust_with_zones_keeps_only_what_is_proved_and_clear(round_):
    """Step 6 on the middle holes' round: the search runs (its candidates counted), what it keeps (here
    nothing cuts the standing within the makespan slack) is proved with the round's own conflicts, the
    re-timed nominal round is clear, the standing is not worse; with zones.choose = false the round is
    the one without zones."""
    from pipeline.events.draws import DrawSettings
    from pipeline.events.zone_choice import ZoneSettings, prove
    from pipeline.events.zones import NO_ZONES

    inst, oracle, tl, plain = round_
    rr = robust_round(inst, tl, oracle, zone_search=(ZoneSettings(), DrawSettings(count=200)))
    assert rr.problem is None and rr.stats["zone_candidates"] > 0 and rr.stats["zones"] == len(rr.zones.names)
    assert rr.stats["zone_standing_p95_after"] <= rr.stats["zone_standing_p95_before"]
    assert scan(rr.timeline, oracle) is None
    conflict = np.zeros((len(rr.actions), len(rr.actions)), bool)
    pairs = rr.conflicts.conflicting
    conflict[pairs[:, 0], pairs[:, 1]] = conflict[pairs[:, 1], pairs[:, 0]] = True
    assert prove(rr.actions, rr.interlocks, rr.zones, conflict) is None
    # the proof is not vacuous on this round: without its interlocks the middle drills may overlap
    assert prove(rr.actions, np.zeros((0, 2), int), NO_ZONES, conflict) is not None
    off = robust_round(inst, tl, oracle, zone_search=(ZoneSettings(choose=False), DrawSettings(count=200)))
    assert off.zones is NO_ZONES and np.array_equal(off.interlocks, plain.interlocks)
