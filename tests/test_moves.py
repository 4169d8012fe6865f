"""Collision-free moves of one boom of the twin rig (docs/reference.md section 7).

Every returned motion is re-checked here without pipeline.motion.checks or .path: each segment is
rebuilt from its waypoints with timing.profile, sampled in time at 5x the checks' resolution (no
point moves more than 2 mm between samples, by a crude lever bound of this file's own: the whole
chain's length for every revolute joint), and measured with the SafetyModel and the rig's boom-boom
clearance directly.

The configurations (boom L; degrees, metres) were found by a seeded search of random in-range
configurations clear of the tunnel, of L itself and of R at park; each test first asserts the premise
(for example that the straight line does hit the arch) with the independent sampler.
"""

import dataclasses
import math

import numpy as np
import pytest
import torch

from pipeline.assembly.rig import load_rig
from pipeline.core.config import load_group_file
from pipeline.geometry.tunnel import SURFACES
from pipeline.motion.moves import PlannerSettings, plan_move
from pipeline.motion.timing import motion_from_config, move_time, profile

D = torch.float64
FINE = 0.01 / 5  # m: 5x the checks' 1 cm
# Straight line breaks the arch (tunnel); retracting the feed clears it.
ARCH_A = [4.255, 47.243, 3.4937, -66.567, -24.132, -42.54, 77.993, 1.5044]
ARCH_B = [-40.004, 61.082, 3.0658, -151.902, 46.114, 19.193, 14.646, 2.9619]
# Straight line breaks the wall; retract does not help; the planner does.
WALL_A = [-0.695, 45.254, 3.9425, 18.445, -14.781, 7.416, 108.503, 1.5107]
WALL_B = [-11.546, 1.257, 4.1743, 18.462, -14.519, 71.005, -170.767, 2.8146]
# Straight line breaks the boom's own self distance (feed against boom).
SELF_A = [-16.946, 25.019, 3.0563, -153.226, -7.087, -0.129, 57.599, 2.4619]
SELF_B = [-13.776, 52.896, 3.5356, -73.787, -3.897, 32.003, -37.898, 1.1218]
# Straight line runs through R standing at park; both ends are clear of it.
THROUGH_A = [13.654, 11.363, 3.4897, 144.3, 10.614, 17.196, 131.379, 1.3758]
THROUGH_B = [-0.076, 14.51, 3.8818, -169.514, -57.565, 17.05, -178.158, 2.7767]
# Inside R's standing place at park (boom-boom clearance about -0.43 m), clear of tunnel and self.
INTO_R = [-27.488, -5.978, 3.2858, 59.617, -23.335, -5.875, -116.992, 1.4645]
PLANNER = PlannerSettings(iterations=20000, simplify_steps=40, seed=1)  # counts: reproducible


@pytest.fixture(scope="module")
def rig(safety):
    return load_rig("twin", safety.tunnel, safety.distances, safety.points_per_capsule)


@pytest.fixture(scope="module")
def limits(jumbo8):
    return motion_from_config(load_group_file("motion", "jumbo8"), jumbo8).joints


def _q(boom, values):
    return torch.tensor([math.radians(v) if j.revolute else v for v, j in zip(values, boom.joints, strict=True)],
                        dtype=D)


def _crude_lever(boom):
    """Every capsule point is within the chain's whole length of any joint axis point."""
    reach = sum(abs(r[1]) + abs(r[3]) for r in boom.rows) + sum(j.upper for j in boom.joints if not j.revolute)
    reach += max(abs(p.along_z) for b in boom.bodies.values() for p in (b.start, b.end)) + math.hypot(*boom.tool)
    return torch.tensor([reach if j.revolute else 1.0 for j in boom.joints], dtype=D)


def _samples(waypoints, limits, lever, step=FINE):
    """Times (from the move's start) and joints of the rest-to-rest straight segments through
    ``waypoints``, every ``step`` metres of point travel at the segment's top path speed."""
    plain = dataclasses.replace(limits, wrap=(False,) * len(limits.wrap))
    ts, qs, start = [], [], 0.0
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        p = profile(a, b, plain)
        T = float(p.duration)
        speed = float((p.step.abs() * lever).sum() * p.peak)  # m/s, bound of any point's speed
        n = max(2, math.ceil(T * speed / step) + 1)
        t = torch.linspace(0, T, n, dtype=D)
        ts.append(t + start)
        qs.append(p.positions(t))
        start += T
    return torch.cat(ts), torch.cat(qs)


def _oracle(rig, i, t, q, other_at):
    """Smallest self, tunnel and boom-boom clearance of boom ``i`` at ``q`` (SafetyModel, boom pair)."""
    c = rig.booms[i].clearances(q)
    j = 1 - i
    boom = rig.boom_clearance(i, q, j, other_at(t))
    return {"self": float(c["self"].min()), "tunnel": float(torch.stack([c[k] for k in SURFACES]).min()),
            "boom": float(boom.min())}


def _standing(rig, j):
    return lambda t: rig.booms[j].park.expand(t.shape[0], -1)


def _assert_clear(rig, move, limits, other_at=None, premise=None):
    """The move is clear by the independent sampler, its minima agree with it, and, where given, the
    straight line from its start to its end is not."""
    boom = rig.booms[0].boom
    lever = _crude_lever(boom)
    other_at = other_at or _standing(rig, 1)
    t, q = _samples(move.path.waypoints, limits, lever)
    assert float(t[-1]) == pytest.approx(move.duration, abs=1e-9)
    fine = _oracle(rig, 0, t, q, other_at)
    assert min(fine.values()) >= 0, (move.kind, fine)
    for k, v in move.clearances.items():  # the checks' minima are sampled ones, above their certified floor
        assert fine[k] <= v + FINE  # (the true minimum is, and the nearest fine sample is 2 mm of drift from it)
        assert fine[k] >= move.clearance.floor - 1e-12
    if premise is not None:
        wp = move.path.waypoints
        t, q = _samples(torch.stack([wp[0], wp[-1]]), limits, lever, step=0.05)  # one broken sample proves it
        straight = _oracle(rig, 0, t, q, other_at)
        assert straight[premise] < 0, straight
    return fine


def test_straight_clear_move_takes_the_move_time(rig, limits, jumbo8):
    a, b = _q(jumbo8, ARCH_A), _q(jumbo8, THROUGH_A)
    move = plan_move(rig, "L", a, b, limits)
    assert move.kind == "straight" and move.reason == ""
    assert move.duration == pytest.approx(float(move_time(a, b, limits)), abs=1e-12)
    _assert_clear(rig, move, limits)
    assert float(move.q[0].sub(a).abs().max()) == 0 and float(move.t[0]) == 0
    end = move.q[-1] - b  # q4, q7 may arrive a full turn away
    assert torch.allclose(torch.remainder(end + math.pi, 2 * math.pi) - math.pi, torch.zeros(8, dtype=D), atol=1e-12)


def test_straight_into_the_arch_becomes_a_retract_move(rig, limits, jumbo8):
    move = plan_move(rig, "L", _q(jumbo8, ARCH_A), _q(jumbo8, ARCH_B), limits)
    assert move.kind == "retract" and move.reason.startswith("straight: arch")
    feed = move.path.waypoints[1:3, 7]
    assert torch.equal(feed, torch.full((2,), 1.0, dtype=D))  # fed back to q8's lower limit
    _assert_clear(rig, move, limits, premise="tunnel")


@pytest.mark.parametrize("case, premise", [((WALL_A, WALL_B), "tunnel"), ((SELF_A, SELF_B), "self")])
def test_straight_into_the_wall_or_itself_becomes_a_clear_detour(rig, limits, jumbo8, case, premise):
    a, b = (_q(jumbo8, v) for v in case)
    move = plan_move(rig, "L", a, b, limits, planner=PLANNER)
    assert move.kind in ("retract", "planned"), move.reason
    assert move.clear and move.clearance.clear
    _assert_clear(rig, move, limits, premise=premise)


def test_a_move_through_the_other_boom_is_routed_around_it(rig, limits, jumbo8):
    a, b = _q(jumbo8, THROUGH_A), _q(jumbo8, THROUGH_B)
    move = plan_move(rig, "L", a, b, limits, planner=PLANNER)
    assert move.reason.startswith("straight: boom R")
    assert move.kind in ("retract", "planned"), move.reason
    _assert_clear(rig, move, limits, premise="boom")


def test_a_move_into_the_other_booms_standing_place_is_refused(rig, limits, jumbo8):
    a, b = _q(jumbo8, ARCH_A), _q(jumbo8, INTO_R)
    assert float(rig.boom_clearance(0, b, 1, rig.booms[1].park)) < 0  # the premise, directly
    move = plan_move(rig, "L", a, b, limits, planner=PLANNER)
    assert move.kind == "failed" and not move.clear and "refused: the end qb" in move.reason
    assert move.clearances["boom"] < 0 and not move.clearance.clear


def test_moving_other_boom_is_checked_where_it_is_at_each_instant(rig, limits, jumbo8):
    """R moves while L does: L's move is judged against R's rows at the same instants. R lowering its
    boom 10 deg still crosses L's straight line, so L detours, clear by the oracle against R's rows
    interpolated here; R swinging into the space L starts from makes L's move fail, never clear."""
    a, b = _q(jumbo8, THROUGH_A), _q(jumbo8, THROUGH_B)
    for r_to, routed in (([0, -10, 3.0, 0, 0, 0, 0, 1.0], True), ([10, 10, 3.5, 0, 0, 0, 0, 2.0], False)):
        r_move = plan_move(rig, "R", rig.booms[1].park, _q(jumbo8, r_to), limits, others={"L": a}, kinds=("straight",))
        assert r_move.kind == "straight"
        timed = r_move.timed(0.0)

        def other_at(t, timed=timed):  # R's rows, linear in t (numpy, not Timed.at)
            return torch.stack([torch.from_numpy(np.interp(t.numpy(), timed.t.numpy(), timed.q[:, k].numpy()))
                                for k in range(8)], -1)

        move = plan_move(rig, "L", a, b, limits, others={"R": timed}, planner=PLANNER)
        assert move.reason.startswith("straight: boom R")
        if routed:
            assert move.kind in ("retract", "planned"), move.reason
            _assert_clear(rig, move, limits, other_at=other_at, premise="boom")
        else:
            assert move.kind == "failed" and "sweep" in move.reason and move.clearances["boom"] < 0


def test_rows_stay_within_a_millimetre_and_within_joint_speeds(rig, limits, jumbo8):
    """Between trajectory rows, linear interpolation against the planned motion at quarter points,
    for every capsule end of the boom (capsule points are convex combinations of the ends)."""
    boom, mounted = jumbo8, rig.booms[0]
    plain = dataclasses.replace(limits, wrap=(False,) * 8)
    for a, b in ((ARCH_A, ARCH_B), (ARCH_A, THROUGH_A)):
        move = plan_move(rig, "L", _q(boom, a), _q(boom, b), limits)
        t, q = move.t, move.q
        wp = move.path.waypoints
        segs = [profile(x, y, plain) for x, y in zip(wp[:-1], wp[1:], strict=True)]
        starts = np.cumsum([0.0] + [float(p.duration) for p in segs])

        def planned(times, segs=segs, starts=starts):
            k = np.clip(np.searchsorted(starts, times.numpy(), side="right") - 1, 0, len(segs) - 1)
            return torch.stack([segs[i].positions(torch.tensor([float(x - starts[i])], dtype=D))[0]
                                for i, x in zip(k, times.tolist(), strict=True)])

        assert torch.allclose(q, planned(t), atol=1e-12, rtol=0)  # rows lie on the motion
        frac = torch.tensor([0.25, 0.5, 0.75], dtype=D)
        tm = (t[:-1, None] + frac * (t[1:] - t[:-1])[:, None]).flatten()
        lin = (q[:-1, None] + frac[:, None] * (q[1:] - q[:-1])[:, None]).flatten(0, 1)

        def ends(qq):
            f = mounted.frames(qq)
            return torch.stack([p for name in boom.bodies for p in boom.capsule_ends(f, name)], -2)

        gap = (ends(lin) - ends(planned(tm))).norm(dim=-1).max()
        assert float(gap) <= 1e-3, (move.kind, float(gap))
        assert move.t.shape[0] < 200  # dense only where needed: rows on the ramps, none while cruising
        speed = (q[1:] - q[:-1]).abs() / (t[1:] - t[:-1])[:, None]
        assert bool((speed <= torch.tensor(limits.v, dtype=D) * (1 + 1e-9)).all())


def test_lever_arms_by_hand_and_against_finite_motion(rig, jumbo8, limits):
    """jumbo8 by hand: q1's axis (z at 1.6 m) to the feed: a = 0.35, d3 <= 4.6, a = 0.8, then the feed
    along z8 with |d8 - 4.5| <= 3.5 (start) or d8 <= 3.5 (end): 9.25 m; q2: 4.6 + 0.8 + 3.5 = 8.9 m;
    q4..q7: 0.8 + 3.5 = 4.3 m. Then, for random configurations and steps, no capsule end moves
    farther than sum_i r_i |dq_i| (brute force over the straight line), and the dense check's
    instants keep every capsule end within 1 cm from one instant to the next."""
    from pipeline.motion.checks import lever_arms
    from pipeline.motion.path import Path

    r = lever_arms(jumbo8)
    assert r.tolist() == pytest.approx([9.25, 8.9, 1.0, 4.3, 4.3, 4.3, 4.3, 1.0], abs=1e-12)
    g = torch.Generator().manual_seed(5)
    lo, hi = jumbo8.limits(D)
    qa = lo + (hi - lo) * torch.rand(300, 8, generator=g, dtype=D)
    qb = lo + (hi - lo) * torch.rand(300, 8, generator=g, dtype=D)
    s = torch.linspace(0, 1, 41, dtype=D)[:, None, None]
    line = qa + s * (qb - qa)  # (41, 300, 8)

    def ends(q):
        f = jumbo8.frames(q)
        return torch.stack([p for name in jumbo8.bodies for p in jumbo8.capsule_ends(f, name)], -2)

    e = ends(line)
    moved = (e - e[:1]).norm(dim=-1).amax(-1)  # (41, 300): farthest end from its start
    bound = ((line - qa).abs() * r).sum(-1)
    assert bool((moved <= bound + 1e-12).all())
    assert float((moved / bound.clamp_min(1e-12))[1:].max()) > 0.5  # and not vacuous
    path = Path.through(torch.stack([_q(jumbo8, ARCH_A), _q(jumbo8, WALL_B)]), limits)
    t = path.check_instants(r, 0.01)
    e = ends(path.positions(t))
    assert float((e[1:] - e[:-1]).norm(dim=-1).max()) <= 0.01
    assert t.shape[0] == math.ceil(float((path.segments.step.abs() * r).sum()) / 0.01) + 1


def test_bad_input_is_named(rig, limits, jumbo8):
    from pipeline.core.errors import ConfigError, InputError

    a = _q(jumbo8, ARCH_A)
    with pytest.raises(InputError, match="qb"):
        plan_move(rig, "L", a, a[:7], limits)
    far = a.clone()
    far[2] = 9.0
    with pytest.raises(InputError, match="qb.*outside the joint ranges of boom 'L'"):
        plan_move(rig, "L", a, far, limits)
    with pytest.raises(ConfigError, match="no boom 'X'"):
        plan_move(rig, "X", a, a, limits)
    with pytest.raises(InputError, match="kinds"):
        plan_move(rig, "L", a, a, limits, kinds=("teleport",))
    with pytest.raises(InputError, match="not another boom"):
        plan_move(rig, "L", a, a, limits, others={"L": a})


def test_trio_middle_boom_is_checked_against_both_neighbours(safety, limits, jumbo8):
    """On the trio (8 m drift), M lifting its boom is clear of L and R by the oracle, both standing at
    park; M (mounted 0.8 m above them) swinging 45 deg towards L and lowering its boom 20 deg ends inside L's
    standing place and is refused, naming L."""
    from pipeline.geometry.tunnel import Horseshoe

    trio = load_rig("trio", Horseshoe.from_config(load_group_file("tunnel", "horseshoe_wide")), safety.distances,
                    safety.points_per_capsule)
    m = trio.index("M")
    park = trio.booms[m].park
    lift = park.clone()
    lift[1] = math.radians(20)
    move = plan_move(trio, "M", park, lift, limits, kinds=("straight",))
    assert move.kind == "straight"
    t, q = _samples(move.path.waypoints, limits, _crude_lever(jumbo8))
    c = trio.booms[m].clearances(q)
    assert min(float(c[k].min()) for k in c) >= 0
    gaps = [float(trio.boom_clearance(m, q, j, trio.booms[j].park).min()) for j in (trio.index(n) for n in "LR")]
    assert min(gaps) >= 0
    assert move.clearance.floor - 1e-12 <= min(gaps) <= move.clearances["boom"] + FINE  # as in _assert_clear
    swing = park.clone()
    swing[0], swing[1] = math.radians(45), math.radians(-20)
    assert float(trio.boom_clearance(m, swing, trio.index("L"), trio.booms[0].park)) < 0  # the premise
    move = plan_move(trio, "M", park, swing, limits, planner=PLANNER)
    assert move.kind == "failed" and "straight: boom L" in move.reason and "refused: the end qb" in move.reason


def test_a_move_clear_at_its_samples_but_not_certified_is_refined_then_taken(rig, limits, jumbo8):
    """Sampled every 0.2 m of point travel, a clear straight move's samples are all clear but the
    certified floor between them is not (the premise). Halving the resolution certifies it (its floors
    a lower bound of an independent 2 mm sampling), so plan_move takes the straight line; without
    refinement it refuses it, naming the short floor, though no sample broke."""
    from pipeline.motion.checks import certify_path, check_path, margins
    from pipeline.motion.path import Path, unwrapped

    a, b = _q(jumbo8, ARCH_A), _q(jumbo8, THROUGH_A)
    path = Path.through(torch.stack([a, unwrapped(a, b, limits)]), limits)  # q4, q7 the short way, as plan_move
    m = margins(0.001)
    coarse = check_path(rig, 0, path, resolution=0.2)
    assert coarse.clear and coarse.sampled_at_least(m) and not coarse.certified(m), coarse  # the premise
    fine = certify_path(rig, 0, path, m, resolution=0.2, refinements=6)
    assert fine.certified(m) and fine.instants > coarse.instants
    t, q = _samples(path.waypoints, limits, _crude_lever(jumbo8))
    independent = _oracle(rig, 0, t, q, _standing(rig, 1))
    for kind in ("self", "tunnel", "boom"):
        assert independent[kind] >= fine.floors[kind] - 1e-12 and fine.floors[kind] >= m[kind]
    taken = plan_move(rig, "L", a, b, limits, kinds=("straight",), resolution=0.2,
                      planner=PlannerSettings(refinements=6))
    assert taken.kind == "straight" and taken.clearance.certified(m)
    refused = plan_move(rig, "L", a, b, limits, kinds=("straight",), resolution=0.2,
                        planner=PlannerSettings(refinements=0))
    assert refused.kind == "failed" and "certified floor short" in refused.reason, refused.reason


def test_ompl_is_seeded_and_limited_by_counts(rig, limits, jumbo8):
    """The same seed and counts give the same planned path, also after a search with another seed
    (OMPL's samplers are seeded anew before each search); one iteration finds nothing and says so."""
    a, b = _q(jumbo8, WALL_A), _q(jumbo8, WALL_B)

    def planned(seed, iterations=20000):
        return plan_move(rig, "L", a, b, limits, kinds=("planned",),
                         planner=PlannerSettings(iterations=iterations, simplify_steps=40, seed=seed))

    one, two = planned(3), planned(3)
    assert one.kind == "planned" and torch.equal(one.path.waypoints, two.path.waypoints)
    planned(5)
    assert torch.equal(planned(3).path.waypoints, one.path.waypoints)
    none = planned(3, iterations=1)
    assert none.kind == "failed" and "1 iterations" in none.reason, none.reason
