"""Move and drilling times (docs/reference.md, section 7) against hand computations, and the sampled profiles."""

import math

import pytest
import torch

from pipeline.core.config import load_group_file
from pipeline.core.errors import ConfigError
from pipeline.motion.timing import (
    drilling_time,
    full_turn,
    joint_times,
    motion_from_config,
    move_time,
    profile,
    rig_motions,
    wrap,
)

D = torch.float64
r = math.radians
PARK = [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 1.0]
SPEEDS = [r(15), r(12), 0.3, r(20), r(15), r(15), r(25), 0.5]  # docs/reference.md section 7


@pytest.fixture(scope="module")
def motion(jumbo8):
    return motion_from_config(load_group_file("motion", "jumbo8"), jumbo8)


def _move(limits, **steps):
    """A move from PARK changing the named joints (``q1=r(30)``) by the given amounts."""
    qa = torch.tensor(PARK, dtype=D)
    qb = qa.clone()
    for name, step in steps.items():
        qb[int(name[1:]) - 1] += step
    return qa, qb


def test_motion_file_holds_the_spec_speeds(motion, jumbo8):
    assert motion.joints.names == tuple(jumbo8.joint_names)
    assert motion.joints.v == pytest.approx(SPEEDS, rel=1e-15)
    assert motion.joints.a == pytest.approx([v / 0.5 for v in SPEEDS], rel=1e-15)
    assert full_turn(jumbo8) == (False, False, False, True, False, False, True, False)  # q4, q7 turn fully


@pytest.mark.parametrize("name, step, expected", [
    ("q1", r(30), 30 / 15 + 0.5),              # trapezoid: reaches 15 deg/s after 0.5 s (3.75 deg)
    ("q1", r(7.5), 7.5 / 15 + 0.5),            # just reaches v: d = v^2/a = 7.5 deg (= triangle 2 sqrt(d/a))
    ("q1", r(5), 2 * math.sqrt(5 / 30)),       # triangle: a = 30 deg/s^2
    ("q3", 1.2, 1.2 / 0.3 + 0.5),              # prismatic trapezoid
    ("q3", 0.1, 2 * math.sqrt(0.1 / 0.6)),     # prismatic triangle (d < v^2/a = 0.15 m)
    ("q8", -2.0, 2.0 / 0.5 + 0.5),             # direction does not matter
])
def test_one_joint_by_hand(motion, name, step, expected):
    qa, qb = _move(motion.joints, **{name: step})
    assert float(move_time(qa, qb, motion.joints)) == pytest.approx(expected, rel=1e-12)


def test_several_joints_slowest_dominates(motion):
    qa, qb = _move(motion.joints, q1=r(30), q3=0.1, q8=2.0, q5=r(-20))
    # alone: q1 2.5 s, q3 0.816 s, q8 4.5 s, q5 20/15 + 0.5 = 1.833 s
    assert float(move_time(qa, qb, motion.joints)) == pytest.approx(4.5, rel=1e-12)
    assert joint_times(qb - qa, motion.joints).tolist() == pytest.approx(
        [2.5, 0, 2 * math.sqrt(0.1 / 0.6), 0, 20 / 15 + 0.5, 0, 0, 4.5], rel=1e-12)


def test_full_turn_joints_take_the_short_way(motion):
    qa = torch.tensor(PARK, dtype=D)
    qa[3], qa[6] = r(170), r(-175)
    qb = qa.clone()
    qb[3], qb[6] = r(-170), r(175)  # 20 deg and 10 deg across +-180, not 340 and 350
    assert float(move_time(qa, qb, motion.joints)) == pytest.approx(max(20 / 20 + 0.5, 2 * math.sqrt(10 / 50)),
                                                                     rel=1e-12)
    # q5 has +-90 deg and q1 +-45 deg: never wrapped
    qa, qb = _move(motion.joints, q5=r(170))
    assert float(move_time(qa, qb, motion.joints)) == pytest.approx(170 / 15 + 0.5, rel=1e-12)


def test_move_time_is_the_slowest_joint_over_random_moves(motion, jumbo8):
    g = torch.Generator().manual_seed(0)
    lo, hi = jumbo8.limits(D)
    qa, qb = (lo + (hi - lo) * torch.rand(2000, 8, generator=g, dtype=D) for _ in range(2))
    short = torch.where(torch.tensor(full_turn(jumbo8)), torch.remainder(qb - qa + math.pi, 2 * math.pi) - math.pi,
                        qb - qa)
    slowest = joint_times(short, motion.joints).amax(-1)
    assert torch.allclose(move_time(qa, qb, motion.joints), slowest, rtol=1e-12, atol=0)
    # and small moves (triangles) too
    qc = qa + 0.01 * (qb - qa)
    assert torch.allclose(move_time(qa, qc, motion.joints), joint_times(qc - qa, motion.joints).amax(-1),
                          rtol=1e-12, atol=0)


def test_no_move_takes_no_time(motion):
    q = torch.tensor(PARK, dtype=D)
    p = profile(q, q, motion.joints)
    assert float(p.duration) == 0.0
    assert torch.equal(p.positions(torch.tensor([0.0, 1.0], dtype=D)), q.expand(2, 8))


@pytest.mark.parametrize("scale", [1.0, 0.02])  # trapezoid, triangle
def test_sampled_profile_starts_at_a_ends_at_b_within_limits(motion, jumbo8, scale):
    g = torch.Generator().manual_seed(1)
    lo, hi = jumbo8.limits(D)
    qa, qb = (lo + (hi - lo) * torch.rand(50, 8, generator=g, dtype=D) for _ in range(2))
    qb = qa + scale * (qb - qa)
    p = profile(qa, qb, motion.joints)
    T = p.duration
    k = 4001
    t = T[:, None] * torch.linspace(0, 1, k, dtype=D)
    q = p.positions(t)  # (50, k, 8)
    assert q.shape == (50, k, 8)
    assert torch.equal(q[:, 0], qa)
    assert torch.allclose(wrap(q[:, -1], motion.joints), wrap(qb, motion.joints), atol=1e-12, rtol=0)
    dt = (T / (k - 1))[:, None, None]
    vel = (q[:, 1:] - q[:, :-1]) / dt
    acc = (vel[:, 1:] - vel[:, :-1]) / dt
    v, a, _ = motion.joints.tensors()
    assert (vel.abs() <= v * (1 + 1e-9)).all()
    assert (acc.abs() <= a * (1 + 1e-6) + 1e-9).all()  # the finite difference straddles the phase changes
    # every joint moves on the straight line from A to B, all at the same fraction, monotonically
    frac = (q - qa[:, None]) / p.step[:, None]  # random moves: every joint moves
    assert torch.allclose(frac, frac[..., :1].expand_as(frac), atol=1e-9, rtol=0)
    assert (frac[..., 0].diff(dim=-1) >= -1e-12).all()
    # the slowest joint reaches its speed (trapezoid) or its acceleration (triangle): the move is no slower
    # than it must be
    top = (vel.abs() / v).amax(dim=(-2, -1))
    if scale == 1.0:
        assert (top > 1 - 1e-3).all()
    else:
        assert ((acc.abs() / a).amax(dim=(-2, -1)) > 1 - 1e-2).all() and (top < 1).all()


def test_profile_positions_at_hand_times(motion):
    """q8 over 2 m: accelerates for 0.5 s at 1 m/s^2 (0.125 m), cruises at 0.5 m/s, total 4.5 s."""
    qa, qb = _move(motion.joints, q8=2.0)
    p = profile(qa, qb, motion.joints)
    q8 = p.positions(torch.tensor([0.25, 0.5, 2.25, 4.0, 4.25, 4.5, 9.0], dtype=D))[:, 7] - 1.0
    assert q8.tolist() == pytest.approx([0.03125, 0.125, 1.0, 1.875, 2.0 - 0.03125, 2.0, 2.0], abs=1e-12)


def test_drilling_time_by_hand(motion):
    # 10 s collaring + 4 m at 2.5 m/min (96 s) + 4 m of retraction at 1 m/s (4 s)
    assert drilling_time(4.0, motion.drilling) == pytest.approx(110.0, rel=1e-15)
    lengths = torch.tensor([0.0, 1.0, 4.5], dtype=D)
    assert drilling_time(lengths, motion.drilling).tolist() == pytest.approx([10.0, 35.0, 122.5], rel=1e-15)


def _cfg(**changes):
    cfg = load_group_file("motion", "jumbo8")
    cfg.update(changes)
    return cfg


@pytest.mark.parametrize("cfg, message", [
    (_cfg(joint_speeds={"q1": 15}), r"^motion\.joint_speeds must list every joint.*missing \['q2'"),
    (_cfg(joint_speeds={**{f"q{i}": 1 for i in range(1, 9)}, "q9": 1}), r"unknown \['q9'\]"),
    (_cfg(joint_speeds={**{f"q{i}": 1 for i in range(1, 9)}, "q3": -0.3}), r"^motion\.joint_speeds\.q3 = -0\.3"),
    (_cfg(joint_speeds=None), r"^motion\.joint_speeds = None: expected a mapping"),
    (_cfg(accel_time=0), r"^motion\.accel_time = 0\.0: must be > 0"),
    (_cfg(drilling={"rate_m_per_min": 0}), r"^motion\.drilling\.rate_m_per_min = 0\.0: must be > 0"),
    # durations have upper bounds (a hole's times are summed over the round)
    (_cfg(accel_time=1e9), r"^motion\.accel_time = 1000000000\.0: must be <= 60"),
    (_cfg(drilling={"collaring_s": 1e300}), r"^motion\.drilling\.collaring_s = 1e\+300: must be <= 3600"),
    (_cfg(jerk=1), r"^motion\.jerk: unknown setting"),
    (_cfg(boom="huang9"), r"^motion\.boom = 'huang9': these motion settings are for booms of kind 'huang9', not "
                          r"for boom 'jumbo8'"),
])
def test_bad_motion_settings_name_the_setting(jumbo8, cfg, message):
    with pytest.raises(ConfigError, match=message):
        motion_from_config(cfg, jumbo8)


def test_the_motion_is_the_composed_node_with_its_overrides(jumbo8):
    """`motion.*` on the command line reaches the model: q1 at 7.5 deg/s (not the file's 15) and 1 s to speed."""
    from pipeline.core.config import compose

    node = compose(["motion.joint_speeds.q1=7.5", "motion.accel_time=1.0"]).motion
    m = motion_from_config(node, jumbo8)
    assert m.joints.v[0] == pytest.approx(math.radians(7.5), rel=1e-15)
    assert m.joints.a[0] == pytest.approx(math.radians(7.5) / 1.0, rel=1e-15)
    assert m.joints.v[1] == pytest.approx(math.radians(12), rel=1e-15)  # the file's, untouched
    # a 30 deg swing alone: 30/7.5 + 1.0 = 5 s (the file's speeds give 30/15 + 0.5 = 2.5 s)
    qb = torch.zeros(8, dtype=D)
    qb[0] = math.radians(30)
    assert float(move_time(torch.zeros(8, dtype=D), qb, m.joints)) == pytest.approx(5.0, rel=1e-12)


def test_a_rig_boom_of_another_kind_is_refused_by_name(jumbo8):
    from types import SimpleNamespace

    from pipeline.assembly.build import load_boom

    booms = [SimpleNamespace(name="L", boom=jumbo8), SimpleNamespace(name="X", boom=load_boom("huang9"))]
    with pytest.raises(ConfigError, match=r"^rig boom 'X' \(a 'huang9'\): motion\.boom = 'jumbo8'"):
        rig_motions(load_group_file("motion", "jumbo8"), booms)
    assert len(rig_motions(load_group_file("motion", "jumbo8"), booms[:1])) == 1
