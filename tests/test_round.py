"""The round: routing, timeline and conflict loop, baselines, lower bound and tables.

Two kinds of instances: synthetic matrices (routing, bounds; a set oracle that says which node pairs
conflict), and the real twin rig with jumbo8 joint solutions made by forward kinematics (holes are
where those joints put the drill end, so no IK is needed), checked with the real clearances.
"""

import importlib.util
import math

import numpy as np
import pytest
import torch
import yaml
from fk_rounds import boom_joints

from pipeline.assembly.rig import load_rig
from pipeline.core.config import PROJECT_ROOT, load_group_file
from pipeline.core.errors import ConfigError
from pipeline.motion.checks import lever_arms
from pipeline.motion.timing import motion_from_config, profile
from pipeline.round.baselines import naive_routes, nearest_routes, side_allocation
from pipeline.round.bounds import lower_bound
from pipeline.round.planner import baseline, plan_round, reversed_variant
from pipeline.round.problem import Instance, drill_phases, precedence_indices
from pipeline.round.rig_problem import kinematic_round
from pipeline.round.routing import route
from pipeline.round.settings import RoundSettings, parse_round
from pipeline.round.tables import round_table, summary, trajectory_table
from pipeline.round.timeline import resolve, scan, simulate

D = torch.float64
r = math.radians
FAST = RoundSettings(solution_limit=60, reopt_rounds=3)  # counts: reproducible
SPEC_DRILL = lambda L: 10.0 + L / 2.5 * 60.0 + L / 1.0  # noqa: E731  docs/reference.md section 7, by hand


# ---------------------------------------------------------------- synthetic instances
def synthetic(H=30, B=2, seed=0, unreachable=(), precedence=()):
    """Holes on a 4 m x 4 m face; boom b reaches holes within 2 m of its base in y (and a few more
    are dropped at random, never the last boom of a hole); moves = collar distance / 0.4 m/s + 1 s."""
    g = np.random.default_rng(seed)
    collars = np.stack([np.full(H, 6.5), g.uniform(-2, 2, H), g.uniform(0.5, 4.5, H)], 1)
    base_y = np.linspace(0.8, -0.8, B) if B > 1 else np.zeros(1)
    reach = np.abs(collars[None, :, 1] - base_y[:, None]) <= 2.0
    drop = g.random((B, H)) < 0.15
    reach &= ~(drop & (reach.sum(0) > 1))
    for h in unreachable:
        reach[:, h] = False
    parks = np.stack([np.full(B, 5.0), base_y, np.full(B, 1.6)], 1)
    move = np.stack([np.linalg.norm(np.concatenate([collars, parks[b:b + 1]])[:, None] -
                                    np.concatenate([collars, parks[b:b + 1]])[None], axis=-1) / 0.4 + 1.0
                     for b in range(B)])
    move[:, np.arange(H + 1), np.arange(H + 1)] = 0
    phases = drill_phases(g.uniform(3, 5, H))
    return Instance(tuple(f"B{b}" for b in range(B)), tuple(f"h{i}" for i in range(H)), reach, phases, move,
                    tuple(precedence), collars, base_y, parks)


class SetOracle:
    """Conflict iff a node of boom a's segment and a node of boom b's (standing place, or either end
    of a move) form a pair of ``bad[(a, b)]``: over the whole overlap (first instant = its start)."""

    def __init__(self, bad):
        self.bad = bad

    def check(self, a, sa, b, sb, lo, hi):
        bad = self.bad.get((a, b), set())
        hit = np.array([any((x, y) in bad for x in (ua, va) for y in (ub, vb))
                        for ua, va, ub, vb in zip(sa["u"], sa["v"], sb["u"], sb["v"], strict=True)], bool)
        return np.where(hit, lo, np.inf), np.where(hit, -1.0, 1.0)


NO_CONFLICT = SetOracle({})


def test_routing_respects_reach_and_drills_every_hole_once():
    inst = synthetic(H=40, B=3, seed=1, unreachable=(5, 17))
    assert (inst.reach.sum(0) == 1).any()  # some holes have a single boom: reach matters
    r = route(inst, FAST)
    assert sorted(r.left_out) == [5, 17]
    drilled = [h for route_ in r.routes for h in route_]
    assert sorted(drilled) == [h for h in range(40) if h not in (5, 17)]  # each drillable hole exactly once
    for b, route_ in enumerate(r.routes):
        assert inst.reach[b, route_].all(), f"boom {b} got a hole it cannot drill"


def test_routing_time_dimension_is_the_simulated_makespan():
    """Without conflicts the timeline of the routes has no wait, and its makespan is the routes' own
    sum of moves and drilling per boom (the time dimension's span), by hand."""
    inst = synthetic(H=20, B=2, seed=2)
    r = route(inst, FAST)
    tl = resolve(inst, r.routes, NO_CONFLICT)
    for b, rt in enumerate(r.routes):
        nodes = [inst.n_holes, *rt, inst.n_holes]
        by_hand = sum(inst.move_s[b, u, v] for u, v in zip(nodes[:-1], nodes[1:], strict=True)) + inst.drill_s[rt].sum()
        assert tl.arrive[b][-1] == pytest.approx(by_hand, abs=1e-9)
    assert not tl.repairs


def test_precedence_across_booms_holds():
    inst0 = synthetic(H=16, B=2, seed=3)
    both = np.flatnonzero(inst0.reach.all(0))
    only0 = np.flatnonzero(inst0.reach[0] & ~inst0.reach[1])
    only1 = np.flatnonzero(inst0.reach[1] & ~inst0.reach[0])
    assert len(only0) and len(only1)
    # across booms, each pair in row order (so the plan's row order of naive can keep them)
    pairs = tuple(sorted((int(a), int(b))) for a, b in ((only1[-1], only0[0]), (only0[-1], both[0])))
    inst = synthetic(H=16, B=2, seed=3, precedence=pairs)
    for routes in (route(inst, FAST).routes, naive_routes(inst)):
        tl = resolve(inst, routes, NO_CONFLICT)
        start, end = _drill_intervals(inst, tl)
        for i, j in pairs:
            assert end[i] <= start[j] + 1e-9


def test_precedence_config_names_unknown_holes():
    assert precedence_indices([["a", "c"]], ["a", "b", "c"]) == ((0, 2),)
    with pytest.raises(ConfigError, match="no hole 'x'"):
        precedence_indices([["a", "x"]], ["a", "b"])
    s = parse_round(load_group_file("round", "default"))
    assert s.time_limit_s is None and s.budget_s is None and s.solution_limit > 0 and s.precedence == []
    assert s.reproducible  # counts only by default: no wall-time limit
    with pytest.raises(ConfigError, match="time_limit_s"):
        parse_round({"time_limit_s": 0})
    with pytest.raises(ConfigError, match="precedence"):
        parse_round({"precedence": [["a"]]})


@pytest.mark.parametrize("seed", range(6))
def test_lower_bound_never_exceeds_makespan(seed):
    g = np.random.default_rng(100 + seed)
    B = int(g.integers(1, 4))
    inst = synthetic(H=int(g.integers(1, 25)), B=B, seed=seed)
    # random conflicts between holes of different booms
    bad = {(a, b): {(int(i), int(j)) for i, j in g.integers(0, inst.n_holes, (inst.n_holes, 2))}
           for a in range(B) for b in range(a + 1, B)}
    oracle = SetOracle(bad)
    lb = lower_bound(inst)
    plan = plan_round(inst, oracle, RoundSettings(solution_limit=30, reopt_rounds=2))
    for tl in (plan.timeline, baseline(inst, oracle, "naive", FAST), baseline(inst, oracle, "nearest", FAST)):
        assert tl.conflicts_left == 0 and scan(tl, oracle) is None
        assert lb <= tl.makespan + 1e-9


def test_lower_bound_by_hand():
    """One boom, two holes: bound = drilling + cheapest entry of each hole (park or the other hole)."""
    move = np.array([[[0, 3, 5], [3, 0, 2], [5, 2, 0]]], float)  # from (rows) / to: holes 0, 1, park 2
    phases = np.array([[10, 20, 1], [10, 30, 2]], float)  # drilling 31 s and 42 s
    inst = Instance(("A",), ("a", "b"), np.ones((1, 2), bool), phases, move)
    single = max(5 + 31 + 5, 2 + 42 + 2)  # park -> hole -> park
    entries = 3 + 2  # into a: from b (3 < 5 from park); into b: from park (2 < 3 from a)
    # one boom drills both, so it also returns home at the end: + its shortest return (2, from b)
    assert lower_bound(inst) == pytest.approx(max(single, (31 + 42 + entries) / 1 + 2))
    assert lower_bound(inst) <= 2 + 42 + 3 + 31 + 5  # the best round of the two orders, by hand (83 s)
    two = Instance(("A", "B"), ("a", "b"), np.ones((2, 2), bool), phases, np.concatenate([move, move]))
    assert lower_bound(two) == pytest.approx(max(single, (31 + 42 + entries) / 2))
    assert lower_bound(two) == 46


def test_lower_bound_counts_the_holes_only_one_boom_can_drill():
    """Two booms, but only A can drill either hole: A's own work is the bound, not half of it. By
    hand: A enters a from b (3) and b from park (2), drills 31 + 42 s, returns home from b (2) at the
    least; every round of A alone (park -> b -> a -> park = 2 + 42 + 3 + 31 + 5 = 83 s, or the other
    way, 87 s) is at least that."""
    move = np.array([[[0, 3, 5], [3, 0, 2], [5, 2, 0]]], float)
    phases = np.array([[10, 20, 1], [10, 30, 2]], float)
    reach = np.array([[True, True], [False, False]])
    two = Instance(("A", "B"), ("a", "b"), reach, phases, np.concatenate([move, move]))
    alone = 31 + 42 + (3 + 2) + 2
    assert lower_bound(two) == pytest.approx(alone)
    best = min(2 + 42 + 3 + 31 + 5, 5 + 31 + 3 + 42 + 2)  # both orders of A's round, by hand
    assert lower_bound(two) <= best
    # with both booms able to drill both holes, the shared bound is half as large
    assert lower_bound(Instance(("A", "B"), ("a", "b"), np.ones((2, 2), bool), phases,
                                np.concatenate([move, move]))) < alone


def test_baselines_by_side_and_nearest():
    inst = synthetic(H=24, B=2, seed=4)
    alloc = side_allocation(inst)
    y = inst.collars[:, 1]
    for h in range(inst.n_holes):
        side = 0 if y[h] >= 0 else 1  # boom 0 at y = +0.8
        assert alloc[h] == (side if inst.reach[side, h] else 1 - side)
    nv = naive_routes(inst)
    assert all(r == sorted(r) for r in nv)  # plan row order
    nr = nearest_routes(inst)
    for b, rt in enumerate(nr):
        assert sorted(rt) == nv[b]
        at = inst.park_points[b]
        for k, h in enumerate(rt):  # each next hole is the nearest undrilled one
            rest = rt[k:]
            d = np.linalg.norm(inst.collars[rest] - at, axis=1)
            assert d[0] == pytest.approx(d.min())
            at = inst.collars[h]


# ---------------------------------------------------------------- real kinematics (twin)
@pytest.fixture(scope="module")
def twin(safety):
    return load_rig("twin", safety.tunnel, safety.distances, safety.points_per_capsule)


@pytest.fixture(scope="module")
def motion(jumbo8):
    return motion_from_config(load_group_file("motion", "jumbo8"), jumbo8)


_joints = boom_joints  # joints around each boom's face region (feed near +x, q7 picks its side)


MID_L = [r(3), 0.0, 3.5, 0.0, 0.0, r(-3), 0.0, 2.5]  # L's feed on its inner side: collar near y = +0.2
MID_R = [r(-3), 0.0, 3.5, 0.0, 0.0, r(3), r(180), 2.5]  # R's feed on its inner side: collar near y = -0.2


def _face(twin, motion, n_side, seed, mids=True, lengths=4.0, unreachable=0, settings=FAST):
    """Holes of L (feed outside), holes of R, and optionally the two middle holes (first in the plan:
    L's then R's), which conflict when drilled together. Each hole is drillable by the boom whose
    joints made it; ``unreachable`` more holes no boom can drill."""
    qL, qR = _joints(n_side, seed, 180), _joints(n_side, seed + 1, 0)
    if mids:
        qL, qR = torch.cat([torch.tensor([MID_L], dtype=D), qL]), torch.cat([torch.tensor([MID_R], dtype=D), qR])
    nL, nR = len(qL), len(qR)
    H = nL + nR + unreachable
    nan = lambda k: torch.full((k, 8), math.nan, dtype=D)  # noqa: E731
    order = [0, nL] + [k for k in range(H) if k not in (0, nL)] if mids else list(range(H))
    jL = torch.cat([qL, nan(nR + unreachable)])[order]
    jR = torch.cat([nan(nL), qR, nan(unreachable)])[order]
    reach = np.zeros((2, H), bool)
    reach[0, :nL], reach[1, nL:nL + nR] = True, True
    reach = reach[:, order]
    with torch.inference_mode():
        cL, cR = twin.booms[0].tool_pose(qL)[0], twin.booms[1].tool_pose(qR)[0]
    collars = torch.cat([cL, cR, torch.tensor([[6.5, 0.0, 6.5]] * unreachable, dtype=D)])[order].numpy()
    ids = [f"h{k:02d}" for k in range(H)]
    reasons = tuple("" if reach[:, k].any() else "every boom: unreachable (test)" for k in range(H))
    return kinematic_round(twin, ids, [jL, jR], reach, np.full(H, lengths), [motion, motion], collars,
                           settings=settings, reasons=reasons)


def _drill_intervals(inst, tl):
    start, end = np.full(inst.n_holes, np.nan), np.full(inst.n_holes, np.nan)
    for b, rt in enumerate(tl.routes):
        start[rt] = tl.arrive[b][:-1]
        end[rt] = tl.arrive[b][:-1] + inst.drill_s[rt]
    return start, end


@pytest.fixture(scope="module")
def face(twin, motion):
    inst, oracle = _face(twin, motion, 6, seed=0)
    plan = plan_round(inst, oracle, FAST)
    naive = baseline(inst, oracle, "naive", FAST)
    return inst, oracle, plan, naive


def test_the_middle_pair_conflicts_and_is_never_drilled_at_the_same_time(face):
    inst, oracle, plan, naive = face
    assert oracle.standing(0, 1)[0, 1] < 0  # the deliberately conflicting pair (rows 0 and 1)
    for tl in (plan.timeline, naive):
        start, end = _drill_intervals(inst, tl)
        assert end[0] <= start[1] + 1e-9 or end[1] <= start[0] + 1e-9
        assert tl.conflicts_left == 0 and not tl.sequential


def test_optimised_round_beats_naive_which_must_wait(face):
    inst, oracle, plan, naive = face
    waits = [rec["wait_s"] for rec in naive.repairs]
    assert sum(waits) > 60  # naive drills both middle holes first: one boom waits out the other's drilling
    assert plan.timeline.makespan < naive.makespan
    assert plan.lower_bound_s <= plan.timeline.makespan


def test_drilling_intervals_last_the_spec_time(face, motion):
    inst, oracle, plan, _ = face
    table = round_table(inst, plan.timeline, [q.numpy() for q in oracle.joints], motion.joints.names)
    assert list(table["hole_id"]) == list(inst.hole_ids) and (table["status"] == "ok").all()
    assert np.allclose(table["t_end"] - table["t_start"], SPEC_DRILL(4.0), atol=1e-9, rtol=0)
    traj = trajectory_table(inst, plan.timeline, oracle, motion.joints.names)
    for _, row in table.iterrows():
        rows = traj[traj["hole_id"] == row["hole_id"]]
        assert list(rows["event"]) == ["collar", "drill", "retract"] and (rows["boom"] == row["boom"]).all()
        assert rows["t"].tolist() == pytest.approx([row["t_start"], row["t_start"] + 10, row["t_start"] + 106])
        later = traj[(traj["boom"] == row["boom"]) & (traj["t"] > rows["t"].max())]
        assert later["t"].min() >= row["t_end"] - 1e-9  # the boom holds the hole until retraction ends
        q = rows[list(motion.joints.names)].to_numpy()
        assert np.ptp(q, axis=0).max() == 0  # joints held throughout


def _interp(traj, boom, names, t):
    rows = traj[traj["boom"] == boom]
    return np.stack([np.interp(t, rows["t"], rows[n]) for n in names], -1)


def _round_checker():
    """The independent round checker's own package (scripts/round_check/, which imports nothing of
    ``pipeline``), loaded from its script as tests/test_check_round.py loads it."""
    spec = importlib.util.spec_from_file_location("check_round_script", PROJECT_ROOT / "scripts" / "check_round.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def boom_boom_distances(checker, boom_yaml: dict, rig_yaml: dict, traj, t: np.ndarray) -> np.ndarray:
    """``(len(t),)`` least capsule-capsule distance between the rig's two booms at instants ``t``: the
    trajectory rows interpolated linearly, the checker's numpy FK of the boom YAML, each boom's base from
    the rig YAML added (no rotation), the checker's clamped segment-segment distance less both radii.
    Nothing of the planner's geometry (kinematics, rig mounting, BoomPair) is used."""
    model = checker.boom.BoomModel(boom_yaml, "conf/boom/jumbo8.yaml")
    points = []
    for spec in rig_yaml["booms"]:
        q = _interp(traj, spec["name"], model.joint_names, t)
        points.append(model.body_points(model.frames(q)) + np.asarray(spec["base"], float))  # (N, bodies, 2, 3)
    radii = np.array([b.radius for b in model.bodies])
    least = np.full(len(t), np.inf)
    for i in range(len(model.bodies)):
        for j in range(len(model.bodies)):
            a, b = points[0][:, i], points[1][:, j]
            gap = checker.distance.segment_distance(a[:, 0], a[:, 1], b[:, 0], b[:, 1]) - radii[i] - radii[j]
            least = np.minimum(least, gap)
    return least


def test_boom_boom_distance_by_the_independent_checkers_geometry_keeps_d_boom(face, motion):
    """The planned round's trajectory table, interpolated linearly every 5 ms, judged by geometry that
    shares no code with the planner: the forward kinematics and segment distance of the independent
    checker (scripts/round_check/) on conf/boom/jumbo8.yaml, the bases and d_boom read from
    conf/rig/twin.yaml. Every instant keeps d_boom, and the middle pair comes close enough that a round
    that did not keep the booms apart would fail."""
    inst, oracle, plan, _ = face
    traj = trajectory_table(inst, plan.timeline, oracle, motion.joints.names)
    boom_yaml = yaml.safe_load((PROJECT_ROOT / "conf/boom/jumbo8.yaml").read_text())
    rig_yaml = yaml.safe_load((PROJECT_ROOT / "conf/rig/twin.yaml").read_text())
    assert [b["name"] for b in rig_yaml["booms"]] == list(inst.booms)
    d_boom = float(rig_yaml["d_boom"])
    t = np.arange(0.0, plan.timeline.makespan + 0.005, 0.005)
    checker = _round_checker()
    least = np.concatenate([boom_boom_distances(checker, boom_yaml, rig_yaml, traj, t[s:s + 20000])
                            for s in range(0, len(t), 20000)])
    k = int(np.argmin(least))
    assert least[k] >= d_boom, f"boom-boom distance {least[k]:.4f} m < d_boom {d_boom} m at t = {t[k]:.3f} s"
    assert least[k] < d_boom + 0.5  # the middle pair brings the booms close: the check is not vacuous


def test_trajectory_rows_respect_joint_speeds_and_the_1mm_rule(face, motion, jumbo8, twin):
    inst, oracle, plan, _ = face
    names = motion.joints.names
    traj = trajectory_table(inst, plan.timeline, oracle, names)
    v = np.array(motion.joints.v)
    for name in inst.booms:
        rows = traj[traj["boom"] == name]
        assert (np.diff(rows["t"]) > 0).all()
        speed = np.abs(np.diff(rows[list(names)].to_numpy(), axis=0)) / np.diff(rows["t"].to_numpy())[:, None]
        assert (speed <= v * (1 + 1e-9)).all()
        assert rows["event"].iloc[0] == "park" and rows["event"].iloc[-1] == "done"
    # every move: points of the interpolated rows within 1 mm of the planned profile (midpoints of rows)
    tl, worst = plan.timeline, 0.0
    for b, rt in enumerate(tl.routes):
        name, nodes = inst.booms[b], [inst.n_holes, *rt, inst.n_holes]
        q_cur = oracle.joints[b][inst.n_holes]
        for k in range(len(nodes) - 1):
            prof = profile(q_cur, oracle.joints[b][nodes[k + 1]], motion.joints)
            ms = tl.move_start[b][k]
            rows = traj[(traj["boom"] == name) & (traj["t"] >= ms - 1e-12) & (traj["t"] <= ms + float(prof.duration))]
            tm = ((rows["t"].to_numpy()[1:] + rows["t"].to_numpy()[:-1]) / 2)
            tm = np.concatenate([tm, np.linspace(ms, ms + float(prof.duration), 50)])
            exact = prof.positions(torch.as_tensor(tm - ms, dtype=D))
            lin = torch.as_tensor(_interp(traj, name, names, tm))
            with torch.inference_mode():
                for body in jumbo8.bodies:
                    for e_exact, e_lin in zip(jumbo8.capsule_ends(jumbo8.frames(exact), body),
                                              jumbo8.capsule_ends(jumbo8.frames(lin), body), strict=True):
                        worst = max(worst, float((e_exact - e_lin).norm(dim=-1).max()))
            q_cur = prof.start + prof.step  # continuous along the file (full-turn joints unwrapped)
    assert worst <= 0.001 + 1e-9


def test_lever_arms_hold_for_the_round_oracle(jumbo8):
    """Every capsule end a revolute joint moves (bodies beyond its axis frame) lies within the bound
    of that joint's axis (random configurations): the oracle's speed bound."""
    lever = lever_arms(jumbo8)
    g = torch.Generator().manual_seed(7)
    lo, hi = jumbo8.limits(D)
    q = lo + (hi - lo) * torch.rand(4000, 8, generator=g, dtype=D)
    f = jumbo8.frames(q)
    for i, j in enumerate(jumbo8.joints):
        if not j.revolute:
            continue
        moved = [p for name, body in jumbo8.bodies.items() for p, e in zip(
            jumbo8.capsule_ends(f, name), (body.start, body.end), strict=True) if e.frame >= j.row + 1]
        assert moved, j.name
        o, z = f[:, j.row + 1, :3, 3], f[:, j.row + 1, :3, 2]
        rel = torch.stack(moved, -2) - o[:, None]
        dist = (rel - (rel * z[:, None]).sum(-1, keepdim=True) * z[:, None]).norm(dim=-1)
        assert float(dist.max()) <= lever[i] + 1e-9, j.name


def test_single_hole_plan(twin, motion):
    inst, oracle = _face(twin, motion, 1, seed=5, mids=False)
    inst1, oracle1 = kinematic_round(twin, ["only"], [oracle.joints[0][:1], oracle.joints[1][:1]],
                                     inst.reach[:, :1], [3.0], [motion, motion], inst.collars[:1], settings=FAST)
    plan = plan_round(inst1, oracle1, FAST)
    table = round_table(inst1, plan.timeline, [q.numpy() for q in oracle1.joints], motion.joints.names)
    assert len(table) == 1 and table["status"].iloc[0] == "ok" and table["boom"].iloc[0] == "L"
    assert table["t_end"].iloc[0] - table["t_start"].iloc[0] == pytest.approx(SPEC_DRILL(3.0))
    assert plan.timeline.makespan >= plan.lower_bound_s - 1e-9
    assert plan.timeline.makespan == pytest.approx(plan.lower_bound_s)  # one hole: the bound is exact
    traj = trajectory_table(inst1, plan.timeline, oracle1, motion.joints.names)
    assert set(traj["boom"]) == {"L", "R"}


def test_unreachable_hole_keeps_its_row(twin, motion):
    inst, oracle = _face(twin, motion, 2, seed=6, mids=False, unreachable=1)
    plan = plan_round(inst, oracle, FAST)
    assert plan.left_out == [inst.n_holes - 1]
    table = round_table(inst, plan.timeline, [q.numpy() for q in oracle.joints], motion.joints.names)
    assert len(table) == inst.n_holes and list(table["hole_id"]) == list(inst.hole_ids)
    last = table.iloc[-1]
    assert last["status"] == "unreachable" and "unreachable (test)" in last["reason"] and last["boom"] == ""
    assert (table["status"].iloc[:-1] == "ok").all()
    s = summary(inst, plan.timeline, plan.lower_bound_s, None, None, [m.base for m in twin.booms], twin.d_boom)
    assert s["holes_unreachable"] == 1 and s["holes_drilled"] == inst.n_holes - 1
    assert sum(v["holes"] for v in s["booms"].values()) == inst.n_holes - 1
    assert s["booms"]["L"]["base"] == [0.0, 0.8, 0.0]


def test_summary_times_add_up(face, twin):
    inst, oracle, plan, naive = face
    s = summary(inst, plan.timeline, plan.lower_bound_s, naive, None, [m.base for m in twin.booms], twin.d_boom)
    for b, name in enumerate(inst.booms):
        x = s["booms"][name]
        assert x["drilling_s"] + x["moving_s"] + x["waiting_s"] == pytest.approx(plan.timeline.arrive[b][-1])
    assert s["min_boom_clearance_m"] >= 0.3 and s["naive_makespan_s"] == naive.makespan


def test_instance_rejects_bad_shapes():
    inst = synthetic(H=3, B=2)
    with pytest.raises(ConfigError, match="move_s"):
        Instance(inst.booms, inst.hole_ids, inst.reach, inst.phases, inst.move_s[:, :3, :3])
    with pytest.raises(ConfigError, match="precedence"):
        Instance(inst.booms, inst.hole_ids, inst.reach, inst.phases, inst.move_s, ((0, 0),))


def test_precedence_cycle_is_an_error():
    inst = synthetic(H=4, B=1, precedence=((0, 1),))
    with pytest.raises(ConfigError, match="cycle"):
        simulate(inst, [[1, 0, 2, 3]])


def test_one_boom_reversed_parts_two_booms_that_block_each_other():
    """A at hole 0 blocks B's move into 4, B at 3 blocks A's move into 1: with both booms in route order
    no wait parts them (the timeline falls back to one boom at a time); A's order reversed needs none."""
    H = 6
    reach = np.zeros((2, H), bool)
    reach[0, :3], reach[1, 3:] = True, True
    move = np.full((2, H + 1, H + 1), 2.0)
    move[:, np.arange(H + 1), np.arange(H + 1)] = 0
    inst = Instance(("A", "B"), tuple(f"h{i}" for i in range(H)), reach, drill_phases(np.full(H, 3.0)), move)
    oracle = SetOracle({(0, 1): {(1, 3), (0, 4)}})
    routes = [[0, 1, 2], [3, 4, 5]]
    forward = resolve(inst, routes, oracle, 300)
    assert forward.sequential and forward.makespan == pytest.approx(sum(
        inst.drill_s) + 8 * 2.0)  # each boom park to park alone: 3 holes, 4 moves
    alt = reversed_variant(lambda rt: resolve(inst, rt, oracle, 300), routes, inst)
    assert not alt.sequential and alt.conflicts_left == 0
    assert sorted(map(sorted, alt.routes)) == sorted(map(sorted, routes))
    assert any(a == r[::-1] for a, r in zip(alt.routes, routes, strict=True))
    assert alt.makespan < 0.6 * forward.makespan


def test_candidates_rank_by_conflicts_then_failed_moves_then_makespan():
    """A round with a move nothing made clear loses to one whose moves are all clear, however short it is;
    conflicts left weigh more than either."""
    from pipeline.round.planner import better as _better
    from pipeline.round.timeline import Timeline

    def tl(makespan, failed=0, conflicts=0):
        return Timeline([[0]], [np.zeros(2)], [np.array([1.0, makespan])], 1, failed_moves=failed,
                        conflicts_left=conflicts)

    assert _better(tl(3000.0), tl(2500.0, failed=1))
    assert not _better(tl(2500.0, failed=1), tl(3000.0))
    assert _better(tl(2500.0, failed=1), tl(2000.0, conflicts=1))
    assert _better(tl(2999.0), tl(3000.0)) and not _better(tl(3000.0), tl(3000.0))
    assert _better(tl(9999.0, failed=5), None)


def test_more_sweep_bands_are_read_and_a_bad_one_is_named():
    assert parse_round({"sweep_more_bands_m": [0.5, 2]}).sweep_more_bands_m == [0.5, 2]
    assert parse_round({}).sweep_more_bands_m == [0.75, 1.5, 2.0]
    for bad in ([0], [-1.0], [True], [float("inf")]):
        with pytest.raises(ConfigError, match=r"sweep_more_bands_m"):
            parse_round({"sweep_more_bands_m": bad})


def test_a_seed_with_the_routes_of_another_is_timed_once():
    from pipeline.round.planner import _add_seed

    seeds = {"sweep -y": [[0, 1], [2]]}
    _add_seed(seeds, "sweep -y, band 2 m", [[0, 1], [2]])
    _add_seed(seeds, "sweep -y, band 0.75 m", [[1, 0], [2]])
    assert list(seeds) == ["sweep -y", "sweep -y, band 0.75 m"]
