"""Posture alternatives and their choice along a round's routes (:mod:`pipeline.round.postures`).

Independent values: the alternatives re-checked by forward kinematics against the plan's collars and
directions and by the safety model and the rig's boom-boom clearance to the parks; the recursion
against brute force over every choice; the farthest-point selection against a brute-force pick; the
bound against the reference's bound of instances built from random choices of the alternatives.
"""

import itertools

import numpy as np
import pandas as pd
import pytest
import torch

from pipeline.assembly.rig import build_rig
from pipeline.core.config import load_group_file
from pipeline.motion.timing import move_time, rig_motions
from pipeline.plans.demo_face import demo_face
from pipeline.plans.model import COLLAR
from pipeline.plans.reach import reach_table, rig_solvers
from pipeline.round.bounds import lower_bound
from pipeline.round.from_plan import planned_joints, round_instance
from pipeline.round.postures import _shortest_path, farthest, posture_alternatives, posture_bound
from pipeline.round.settings import RoundSettings, parse_round
from pipeline.solvers.hybrid import HybridSettings

D = torch.float64


@pytest.fixture(scope="module")
def twin(safety):
    rig = build_rig("twin", load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))
    plan = demo_face(safety=safety)
    solvers = rig_solvers(rig, lambda b: None, HybridSettings())
    reach = reach_table(plan, rig, solvers, "hybrid")
    motions = rig_motions(load_group_file("motion", "jumbo8"), rig.booms)
    postures = posture_alternatives(plan, rig, solvers, reach, [m.joints for m in motions], k=3, starts=16)
    return rig, plan, reach, motions, postures


@pytest.fixture(scope="module")
def limits():
    rig = build_rig("single", load_group_file("tunnel", "horseshoe"), load_group_file("safety", "paper"))
    return rig_motions(load_group_file("motion", "jumbo8"), rig.booms)[0].joints


def test_every_alternative_kept_is_exact_clear_and_distinct(twin):
    rig, plan, reach, motions, postures = twin
    collars = torch.tensor(plan.holes[COLLAR].to_numpy(float))
    toes = torch.tensor(plan.holes[["toe_x", "toe_y", "toe_z"]].to_numpy(float))
    axis = (toes - collars) / (toes - collars).norm(dim=-1, keepdim=True)
    B, H, K = postures.ok.shape
    assert (B, K) == (2, 3)
    for b, m in enumerate(rig.booms):
        ok = torch.as_tensor(postures.ok[b])
        assert torch.equal(ok[:, 0], torch.tensor([s == "ok" for s in reach.results[m.name].status]))
        assert torch.equal(postures.q[b][:, 0], reach.results[m.name].q.to(D))  # the reach table's first
        q = postures.q[b][ok]
        h = ok.nonzero()[:, 0]
        p, z = m.tool_pose(q)
        assert float((p - collars[h]).norm(dim=-1).max()) < 1e-5  # the hybrid's tol is 1e-4 mm; the plan's poses
        assert float((z * axis[h]).sum(-1).min()) > 1 - 1e-9
        c = m.safety.clearances_from_frames(m.frames(q))
        assert all(float(v.min()) >= 0 for v in c.values())
        other = 1 - b
        assert float(rig.boom_clearance(b, q, other, rig.booms[other].park.to(D)[None]).min()) >= 0
        gaps = move_time(postures.q[b][:, :, None, :], postures.q[b][:, None, :, :], motions[b].joints)
        both = ok[:, :, None] & ok[:, None, :] & ~torch.eye(K, dtype=torch.bool)
        assert float(gaps[both].min()) >= 2.0  # posture_gap_s: distinct
    assert (postures.ok.sum(axis=2) >= 2).sum() > H  # not vacuous: most holes have another posture


def test_farthest_picks_the_farthest_ok_candidate_at_least_gap_away(limits):
    g = torch.Generator().manual_seed(3)
    H, S, n = 7, 12, 8
    q0 = torch.rand(H, n, generator=g, dtype=D)
    q = q0[:, None] + 2 * torch.rand(H, S, n, generator=g, dtype=D) - 1
    ok = torch.rand(H, S, generator=g) < 0.6
    ok0 = torch.tensor([True] * (H - 1) + [False])
    out, keep = farthest(q0, ok0, q, ok, limits, 3, 2.0)
    assert torch.equal(out[:, 0], q0) and torch.equal(keep[:, 0], ok0)
    assert not keep[-1, 1:].any()  # a hole the boom cannot drill keeps nothing more
    for h in range(H - 1):
        kept = [q0[h]]
        for j in (1, 2):  # brute force: the ok candidate farthest from every kept one, at least 2 s away
            d = torch.stack([move_time(k[None], q[h], limits) for k in kept]).min(dim=0).values
            allowed = ok[h] & (move_time(q0[h][None], q[h], limits) >= 2.0) & (d >= 2.0)
            d = torch.where(allowed, d, torch.tensor(-1.0, dtype=D))
            if float(d.max()) < 0:
                assert not keep[h, j]
                break
            assert keep[h, j] and torch.equal(out[h, j], q[h, int(d.argmax())])
            kept.append(out[h, j])


def test_the_recursion_finds_the_brute_force_cheapest_choice(limits):
    g = torch.Generator().manual_seed(5)
    R, K, n = 5, 3, 8
    cand = torch.rand(R, K, n, generator=g, dtype=D) * 2
    valid = torch.rand(R, K, generator=g) < 0.7
    valid[:, 0] = True
    unary = torch.rand(R, K, generator=g, dtype=D) * 20
    first, last = (30 * (torch.rand(K, generator=g) < 0.3).to(D) for _ in range(2))  # moves that need detours
    mid = 30 * (torch.rand(R - 1, K, K, generator=g) < 0.3).to(D)
    start, park = torch.zeros(n, dtype=D), torch.ones(n, dtype=D)

    def cost(pick):
        qs = [start] + [cand[i, k] for i, k in enumerate(pick)] + [park]
        moves = sum(float(move_time(a, b, limits)) for a, b in itertools.pairwise(qs))
        extra = float(first[pick[0]] + last[pick[-1]]) + sum(float(mid[i, a, b]) for i, (a, b) in
                                                              enumerate(itertools.pairwise(pick)))
        return moves + extra + sum(float(unary[i, k]) for i, k in enumerate(pick))

    choices = [p for p in itertools.product(range(K), repeat=R) if all(valid[i, k] for i, k in enumerate(p))]
    best = min(cost(p) for p in choices)
    picks = _shortest_path(start, cand, valid, unary, park, limits, (first, mid, last))
    assert all(valid[i, int(k)] for i, k in enumerate(picks))
    assert cost([int(k) for k in picks]) == pytest.approx(best, rel=1e-12)


def test_the_posture_bound_bounds_every_choice_and_is_the_spec_bound_for_one(twin):
    rig, plan, reach, motions, postures = twin
    settings = RoundSettings()
    inst, _, joints = round_instance(rig, plan, reach, motions, settings)
    limits = [m.joints for m in motions]
    bound = posture_bound(inst, postures, limits, rig)
    one = type(postures)([q[:, :1] for q in postures.q], postures.ok[:, :, :1])
    assert posture_bound(inst, one, limits, rig) == pytest.approx(lower_bound(inst), rel=1e-12)
    g = np.random.default_rng(0)
    for _ in range(3):  # random choices among the ok alternatives: each instance's own bound is no lower
        chosen = []
        for b in range(len(rig)):
            pick = np.array([g.choice(np.flatnonzero(row)) if row.any() else 0 for row in postures.ok[b]])
            chosen.append(postures.q[b][torch.arange(len(pick)), torch.as_tensor(pick)])
        other, _, _ = round_instance(rig, plan, reach, motions, settings, chosen)
        assert bound <= lower_bound(other) + 1e-9
    assert bound < lower_bound(inst)  # not vacuous: the alternatives offer shorter entries somewhere


def test_a_planned_round_table_gives_its_joints_back(twin):
    rig, plan, reach, motions, postures = twin
    names = list(rig.booms[0].boom.joint_names)
    ids = plan.holes["hole_id"].astype(str).tolist()
    h = int(np.flatnonzero(postures.ok[1].sum(axis=1) >= 2)[0])
    q = postures.q[1][h, 1]
    row = {"hole_id": ids[h], "boom": "R", "status": "ok", **dict(zip(names, q.tolist(), strict=True))}
    table = pd.DataFrame([row])
    joints = planned_joints(rig, plan, reach, table, names)
    assert torch.equal(joints[1][h], q)
    assert torch.equal(joints[0], reach.results["L"].q.to(D))  # every other solution the reach table's
    bad = table.assign(hole_id="nowhere")
    with pytest.raises(Exception, match="nowhere"):
        planned_joints(rig, plan, reach, bad, names)


def test_posture_settings_are_read_and_checked():
    s = parse_round({"postures": 5, "posture_gap_s": 1.5})
    assert (s.postures, s.posture_gap_s) == (5, 1.5)
    with pytest.raises(Exception, match="postures"):
        parse_round({"postures": 0})


def test_the_choice_along_routes_moves_no_longer_than_the_reach_tables_postures(twin):
    from pipeline.round.postures import choose_postures
    from pipeline.round.seeds import sweep_routes
    from pipeline.round.timeline import simulate

    rig, plan, reach, motions, postures = twin
    inst, _, joints = round_instance(rig, plan, reach, motions, RoundSettings())
    routes = sweep_routes(inst, -1, 1.0)
    tl = simulate(inst, routes)
    limits = [m.joints for m in motions]
    chosen = choose_postures(inst, tl, postures, joints, rig, limits, conflict_s=0.0, unclear_s=0.0)

    def moving(q, b):
        park = rig.booms[b].park.to(D)[None]
        path = torch.cat([park, q[torch.as_tensor(routes[b])], park])
        return float(move_time(path[:-1], path[1:], limits[b]).sum())

    for b in range(len(rig)):
        off = np.setdiff1d(np.arange(inst.n_holes), routes[b])
        assert torch.equal(chosen[b][torch.as_tensor(off)], joints[b][torch.as_tensor(off)].to(D))
        on = torch.as_tensor(routes[b])
        kept = (chosen[b][on][:, None, :] == postures.q[b][on]).all(-1) & torch.as_tensor(postures.ok[b][routes[b]])
        assert bool(kept.any(1).all())  # each hole at one of its ok alternatives
        assert moving(chosen[b], b) < moving(joints[b].to(D), b) - 1.0  # shorter, by more than rounding


def test_a_book_carried_to_other_postures_answers_as_a_fresh_one(twin):
    """The second planning takes the first book's answers for moves whose two ends kept their joints:
    the same timeline, statuses, floors, durations and detours as a book that looks at every move again."""
    from pipeline.round.planner import make_book, timed_routes
    from pipeline.round.postures import choose_postures
    from pipeline.round.seeds import sweep_routes

    rig, plan, reach, motions, postures = twin
    settings = RoundSettings()
    inst, oracle, joints = round_instance(rig, plan, reach, motions, settings)
    routes = sweep_routes(inst, -1, 1.0)
    book = make_book(inst, oracle, settings)
    tl = timed_routes(inst, oracle, settings, book, routes)
    chosen = choose_postures(inst, tl, postures, joints, rig, [m.joints for m in motions])
    answers = []
    for carry in (False, True):
        inst2, oracle2, _ = round_instance(rig, plan, reach, motions, settings, chosen)
        book2 = make_book(inst2, oracle2, settings)
        if carry:
            same = np.stack([((a == c).all(dim=1)).numpy() for a, c in zip(oracle.joints, oracle2.joints,
                                                                           strict=True)])
            assert 0 < (~same).sum() < same.size  # some postures changed, most did not
            book2.carry(book, same)
            known = int((book2.status != 0).sum())
            assert known > 0
        # the carried detours' durations go into the instance first, as plan_round applies its book
        answers.append((timed_routes(book2.apply(inst2), oracle2, settings, book2, routes), book2, oracle2))
    (fresh, fb, fo), (carried, cb, co) = answers
    assert carried.makespan == fresh.makespan and carried.repairs == fresh.repairs
    both = (cb.status != 0) & (fb.status != 0)
    assert np.array_equal(cb.status[both], fb.status[both]) and both.sum() > 0
    for kind in ("self", "tunnel"):
        assert np.array_equal(cb.floor[kind][both], fb.floor[kind][both])
    assert cb.durations == {k: v for k, v in fb.durations.items() if k in cb.durations}
    for key in cb.durations:
        assert torch.equal(co.detour(*key).waypoints, fo.detour(*key).waypoints)
    assert any(s != 0 for s in cb.status.ravel()) and len(cb.durations) > 0  # not vacuous: detours carried
