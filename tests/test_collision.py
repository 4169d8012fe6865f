"""Segment distance, tunnel distances, clearances, checks and penalties."""

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline.assembly.build import build_safety
from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SAFETY_KINDS, SafetyDistances, segment_distance
from pipeline.geometry.tunnel import SURFACES, Horseshoe

r = math.radians
D = torch.float64


def _point_segment(x, a, b):
    """Exact distance from points x (..., 3) to one segment a-b (projection, clamped)."""
    ab = b - a
    t = (((x - a) * ab).sum(-1) / (ab * ab).sum(-1)).clamp(0, 1)
    return torch.linalg.vector_norm(x - (a + t.unsqueeze(-1) * ab), dim=-1)


def _brute_segment_distance(p1, q1, p2, q2, n=40001):
    """Dense sampling of the first segment against the exact point-segment distance."""
    s = torch.linspace(0, 1, n, dtype=D).unsqueeze(-1)
    return float(_point_segment(p1 + s * (q1 - p1), p2, q2).min())


def _cases():
    g = torch.Generator().manual_seed(3)
    cases = [torch.randn(4, 3, generator=g, dtype=D) for _ in range(40)]
    p = torch.tensor([0.0, 0.0, 0.0], dtype=D)
    x = torch.tensor([1.0, 0.0, 0.0], dtype=D)
    y = torch.tensor([0.0, 1.0, 0.0], dtype=D)
    cases += [
        torch.stack([p, x, p + 0.5 * y, x + 0.5 * y]),  # parallel, overlapping
        torch.stack([p, x, 2 * x + 0.3 * y, 3 * x + 0.3 * y]),  # parallel, disjoint along the axis
        torch.stack([p, x, 3 * x, 2 * x]),  # collinear, reversed, end gap 1
        torch.stack([p, x, x, x + y]),  # touching at an end point
        torch.stack([p, 2 * x, x - y, x + y]),  # crossing
        torch.stack([p, x, 0.5 * x + y, 0.5 * x + 2 * y]),  # T: end point above an interior point
        torch.stack([p, p, x, x + y]),  # degenerate first segment (a point)
    ]
    return cases


@pytest.mark.parametrize("case", _cases())
def test_segment_distance_matches_brute_force(case):
    p1, q1, p2, q2 = case
    dist, _, _ = segment_distance(p1, q1, p2, q2)
    assert float(dist) == pytest.approx(_brute_segment_distance(p1, q1, p2, q2), abs=1e-4)
    # and symmetric
    assert float(segment_distance(p2, q2, p1, q1)[0]) == pytest.approx(float(dist), abs=1e-12)


def test_segment_distance_batched_and_differentiable():
    cases = torch.stack(_cases())  # (n, 4, 3)
    ends = cases.clone().requires_grad_(True)
    dist, s, t = segment_distance(ends[:, 0], ends[:, 1], ends[:, 2], ends[:, 3])
    assert dist.shape == (len(cases),) and ((s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)).all()
    dist.sum().backward()
    assert torch.isfinite(ends.grad).all()
    singles = torch.stack([segment_distance(*c)[0] for c in cases])
    assert torch.allclose(dist.detach(), singles, atol=1e-12)


def _brute_profile_distance(y, z, tunnel, n=200001):
    """Unsigned distance from (y, z) to each surface by dense sampling of the outline."""
    h, rad = tunnel.wall_height, tunnel.half_width
    s = torch.linspace(0, 1, n, dtype=D)
    walls = [torch.stack([torch.full_like(s, side * rad), s * h], -1) for side in (-1, 1)]
    ang = s * math.pi
    arch = torch.stack([rad * torch.cos(ang), h + rad * torch.sin(ang)], -1)
    pt = torch.tensor([y, z], dtype=D)
    return {
        "wall": float(min(torch.linalg.vector_norm(w - pt, dim=-1).min() for w in walls)),
        "arch": float(torch.linalg.vector_norm(arch - pt, dim=-1).min()),
        "ground": abs(z),
    }


@pytest.mark.parametrize("yz", [(0.0, 1.0), (2.3, 3.3), (-2.4, 1.0), (0.5, 5.5), (1.9, 4.8), (0.0, 3.1), (-1.0, 0.05)])
def test_tunnel_distances_match_sampled_outline(yz):
    tunnel = Horseshoe()
    got = tunnel.surface_distances(torch.tensor(yz[0], dtype=D), torch.tensor(yz[1], dtype=D))
    want = _brute_profile_distance(*yz, tunnel)
    for k in want:
        assert float(got[k]) == pytest.approx(want[k], abs=1e-4), k


def _stacked_surface_distances(tunnel, y, z):
    """The horseshoe's distances written as the study's trainings first computed them: each norm over its own
    stacked (y, z) pair, the wall's and the arch's corner distance apart."""
    from pipeline.geometry.rotations import safe_norm

    def signed_hypot(u, v, sign_of):
        return torch.where(sign_of < 0, -1.0, 1.0).to(u.dtype) * safe_norm(torch.stack([u, v], dim=-1))

    r, h = tunnel.half_width, tunnel.wall_height
    inward = r - y.abs()
    above = z > h
    wall = torch.where(above, signed_hypot(inward, z - h, inward), inward)
    radial = safe_norm(torch.stack([y, z - h], dim=-1))
    arch = torch.where(above, r - radial, signed_hypot(inward, h - z, inward))
    return {"wall": wall, "ground": z, "arch": arch}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_tunnel_distances_and_their_gradients_keep_the_stacked_forms_bits(dtype):
    """The trained networks and drawn hole sets on record were made with the stacked form: the faster one must give
    the same bits, values and gradients, or a rerun of the study would not reproduce them. Points inside and outside
    the profile, on the corners and the springing line, with a loss in which all three surfaces reach each point."""
    tunnel, g = Horseshoe(), torch.Generator().manual_seed(11)
    y = (torch.rand(50_000, generator=g, dtype=D) * 8 - 4).to(dtype)
    z = (torch.rand(50_000, generator=g, dtype=D) * 7 - 1).to(dtype)
    h, rr = tunnel.wall_height, tunnel.half_width
    y[:6] = torch.tensor([rr, -rr, 0.0, rr, rr + 0.5, -0.0], dtype=dtype)
    z[:6] = torch.tensor([h, h, h, 0.0, h, h + rr], dtype=dtype)
    w = torch.randn(3, 50_000, generator=g, dtype=D).to(dtype)
    got = []
    for distances in (tunnel.surface_distances, lambda a, b: _stacked_surface_distances(tunnel, a, b)):
        yy, zz = y.clone().requires_grad_(), z.clone().requires_grad_()
        d = distances(yy, zz)
        (d["wall"] * w[0] + torch.relu(-d["arch"]) * w[1] + d["ground"] * w[2]).sum().backward()
        got.append([d["wall"].detach(), d["arch"].detach(), yy.grad, zz.grad])
    for a, b in zip(got[0][:2], got[1][:2], strict=True):  # the distances, to the sign of a zero
        assert torch.equal(a, b) and torch.equal(a.signbit(), b.signbit())
    for a, b in zip(got[0][2:], got[1][2:], strict=True):  # the gradients: a zero's sign may differ (0 + -0 is 0),
        assert torch.equal(a, b)  # which no sum with a nonzero term, and no optimiser step, can see


def test_tunnel_distance_negative_outside():
    tunnel = Horseshoe()
    d = tunnel.surface_distances(torch.tensor([2.7, 0.0, 0.0], dtype=D), torch.tensor([1.0, -0.2, 5.9], dtype=D))
    assert d["wall"][0] < 0 and d["ground"][1] < 0 and d["arch"][2] < 0
    assert not tunnel.contains(torch.tensor([2.7, 0.0, 0.0], dtype=D), torch.tensor([1.0, -0.2, 5.9], dtype=D)).any()


def test_first_test_vector_is_clean(safety):
    c = safety.clearances(torch.tensor([0, 0, 3.5, 0, 0, 0, 0, 2.5], dtype=D))
    assert all(float(c[k]) > 0 for k in SAFETY_KINDS)
    # boom A-C at y = 0, feed at y = -0.8, both at z = 1.6: 0.8 - 0.2 - 0.15 - 0.1
    assert float(c["self"]) == pytest.approx(0.35, abs=1e-12)


def test_feed_folded_back_onto_boom_is_self_collision(safety):
    # Feed tilted back over the boom: its beam crosses the boom segment.
    q = torch.tensor([0, r(20), 3.5, 0, r(90), 0, r(-90), 2.5], dtype=D)
    v = safety.violations(safety.clearances(q))
    assert bool(v["self"]) and not (bool(v["wall"]) or bool(v["ground"]) or bool(v["arch"]))


def test_boom_pushed_into_floor_is_ground_collision(safety):
    # Boom lowered 30 deg: C at z = 1.6 - 4.6 sin 30; the feed continues the boom line to
    # H at z = 1.6 - (4.6 + 2.5) sin 30, and its deepest checked point is 1 m behind H.
    q = torch.tensor([0, r(-30), 4.6, 0, 0, 0, 0, 2.5], dtype=D)
    c = safety.clearances(q)
    assert bool(safety.violations(c)["ground"])
    boom_depth = 1.6 - 4.6 * 0.5 - 0.2 - 0.1
    feed_depth = 1.6 - (4.6 + 2.5) * 0.5 + 1.0 * 0.5 - 0.15 - 0.1
    assert float(c["ground"]) == pytest.approx(min(boom_depth, feed_depth), abs=1e-9)


def test_more_sample_points_do_not_change_the_answer(jumbo8, safety):
    from pipeline.data.holes import sample_joints

    q = sample_joints(4000, jumbo8, seed=11)
    fine = build_safety(jumbo8, {"width": 5.0, "wall_height": 3.2},
                        {"self": 0.1, "wall": 0.5, "ground": 0.1, "arch": 0.1, "points_per_capsule": 256})
    coarse = safety.violations(safety.clearances(q))
    dense = fine.violations(fine.clearances(q))
    for k in SAFETY_KINDS:
        assert (coarse[k] != dense[k]).double().mean() < 0.005, k


joint_fractions = st.lists(st.floats(0.0, 1.0), min_size=8, max_size=8)


@settings(max_examples=200, deadline=None)
@given(st.lists(joint_fractions, min_size=1, max_size=16))
def test_penalty_zero_exactly_where_check_passes(safety, fractions):
    lo, hi = safety.boom.limits()
    q = lo + torch.tensor(fractions, dtype=D) * (hi - lo)
    c = safety.clearances(q)
    pen, bad = safety.penalties(c), safety.violations(c)
    for k in SAFETY_KINDS:
        assert torch.equal(pen[k] > 0, bad[k]), k
        assert torch.equal(pen[k][bad[k]], -c[k][bad[k]]), k  # the penalty is the depth of the violation


def test_penalty_gradient_finite_everywhere(jumbo8, safety):
    from pipeline.data.holes import sample_joints

    q = sample_joints(2000, jumbo8, seed=5)
    special = torch.tensor(
        [[0, 0, 3.5, 0, 0, 0, 0, 2.5], [0, r(20), 3.5, 0, r(90), 0, r(-90), 2.5], [0, 0, 3.5, 0, 0, r(90), 0, 1.0]],
        dtype=D,
    )
    q = torch.cat([q, special]).requires_grad_(True)
    pen = safety.penalties(safety.clearances(q))
    sum(p.sum() for p in pen.values()).backward()
    assert torch.isfinite(q.grad).all()
    assert (q.grad.abs().sum(-1) > 0).any()  # some configurations are pushed


def test_penalty_gradient_step_increases_clearance(safety):
    q = torch.tensor([0, r(-30), 4.6, 0, 0, 0, 0, 2.5], dtype=D, requires_grad=True)
    before = safety.clearances(q)["ground"]
    safety.penalties(safety.clearances(q))["ground"].backward()
    after = safety.clearances((q - 0.05 * q.grad).detach())["ground"]
    assert float(after) > float(before.detach())


@pytest.mark.parametrize("field", ["self", "wall", "ground", "arch"])
def test_negative_safety_distance_is_rejected(field):
    cfg = {"self": 0.1, "wall": 0.5, "ground": 0.1, "arch": 0.1, field: -0.05}
    with pytest.raises(ConfigError, match=rf"safety.{field} = -0.05: a safety distance cannot be below zero"):
        SafetyDistances.from_config(cfg)


@pytest.mark.parametrize(("extra", "message"), [
    ({"points_per_capsule": 1}, r"safety.points_per_capsule = 1: need at least 2"),
    ({"points_per_capsule": "exact"}, r"safety.points_per_capsule = 'exact': expected an integer"),
    ({"exact_capsules": "yes"}, r"safety.exact_capsules = 'yes': expected true or false"),
])
def test_bad_capsule_settings_are_named(jumbo8, extra, message):
    cfg = {"self": 0.1, "wall": 0.5, "ground": 0.1, "arch": 0.1, **extra}
    with pytest.raises(ConfigError, match=message):
        build_safety(jumbo8, {"width": 5.0, "wall_height": 3.2}, cfg)


# Boom L of the trio rig moving to S20 in the round benchmark's demo-face trio round (2026-12-03): two
# rows of its trajectory file, and the straight joint segment between them that the move certified.
_TRIO_L_A = [0.19590328847017385, 0.20276544154850895, 4.242797727703335, -0.7307539239914863,
             0.12842275728265226, 0.2708233267078712, 3.9230772537163956, 2.409756409334302]
_TRIO_L_B = [0.30099085978366324, 0.00044606608610420206, 4.1425774278331176, -0.2814100881985796,
             -0.03009322593232719, 0.3065558164029162, 4.819745322600663, 2.2579802784601126]


def _dense(safety, n):
    return safety.__class__(safety.boom, safety.tunnel, safety.distances, n, exact=False)


def test_the_exact_check_finds_the_minimum_between_the_16_points():
    """The case the independent round checker found: 16 evenly spaced points keep the wall
    distance by 0.55 mm, the capsule breaks it by 0.78 mm. The exact check finds the capsule's minimum:
    never above a 4 001-point sampling of the axis, and at the move's lowest instant equal to it to 1e-6 m
    (the sampling's own error there is under 1e-7 m: the two agree to 8e-9 m)."""
    from pipeline.assembly.rig import composed_rig
    from pipeline.core.config import compose

    rig = composed_rig(compose(["rig=trio"]))
    boom = rig.booms[rig.index("L")]
    assert boom.safety.exact and boom.safety.points_per_capsule == 16  # the defaults
    s = torch.linspace(0, 1, 201, dtype=D)[:, None]
    q = torch.tensor(_TRIO_L_A, dtype=D) + s * (torch.tensor(_TRIO_L_B, dtype=D) - torch.tensor(_TRIO_L_A, dtype=D))
    frames = boom.frames(q)
    exact = boom.safety.clearances_from_frames(frames)
    sixteen = float(_dense(boom.safety, 16).clearances_from_frames(frames)["wall"].min())
    dense = _dense(boom.safety, 4001).clearances_from_frames(frames)
    assert sixteen > 0 > float(exact["wall"].min())  # the defect, and the exact check sees through it
    for k in SURFACES:
        assert bool((exact[k] <= dense[k] + 1e-12).all()), k
    assert float(exact["wall"].min()) == pytest.approx(float(dense["wall"].min()), abs=1e-6)


@given(st.lists(st.floats(-3.5, 3.5), min_size=4, max_size=4), st.floats(0.0, 1.2))
@settings(max_examples=200, deadline=None)
def test_exact_tunnel_clearance_of_a_segment_is_its_brute_force_minimum(safety, coords, skip):
    """Against brute force: the smallest clearance of 20 001 points along a random capsule, the front ``skip``
    metres left out as for the feed. Inside the profile the two agree within the sampling's own error (the
    distances are 1-Lipschitz in the point). A capsule that leaves it fails, and never less deeply than at
    its 16 samples."""
    assert safety.exact
    p0 = torch.tensor([1.0, coords[0], coords[1] + 3.0], dtype=D)
    p1 = torch.tensor([2.0, coords[2], coords[3] + 3.0], dtype=D)
    length = float(torch.linalg.vector_norm(p1 - p0))
    radius = torch.tensor([0.15], dtype=D)
    clear = safety._tunnel(torch.stack([p0, p1])[None], radius, torch.tensor([skip], dtype=D))[0].amin(-1)
    keep = max(1.0 - skip / max(length, 1e-12), 0.0)
    pts = p0 + torch.linspace(0, 1, 20001, dtype=D)[:, None] * keep * (p1 - p0)
    dist = safety.tunnel.surface_distances(pts[:, 1], pts[:, 2])
    inside = bool(safety.tunnel.contains(pts[:, 1], pts[:, 2]).all())
    for i, k in enumerate(SURFACES):
        brute = float((dist[k] - 0.15 - getattr(safety.distances, k)).min())
        if inside:
            assert float(clear[i]) <= brute + 1e-12, k
            assert float(clear[i]) >= brute - keep * length / 20000 - 1e-12, k
    if not inside:  # then one end is outside the (convex) profile, beyond some surface
        assert float(clear.min()) < 0
    sampled = _dense(safety, 16)._tunnel(torch.stack([p0, p1])[None], radius, torch.tensor([skip], dtype=D))[0]
    assert bool((clear <= sampled.amin(-1) + 1e-15).all())
