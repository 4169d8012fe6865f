"""The rig model: rig files, each boom's clearances seen from its base, parks, and bad rig files."""

import math

import pytest
import torch

from pipeline.assembly.rig import load_rig, rig_booms, rig_spec
from pipeline.core.config import compose, load_group_file
from pipeline.core.errors import ConfigError
from pipeline.geometry.rig import build_rig, parse_rig
from pipeline.geometry.tunnel import Horseshoe

D = torch.float64
HOME = [0, 0, 3.5, 0, 0, 0, 0, 2.5]


@pytest.fixture(scope="module")
def wide():
    return Horseshoe.from_config(load_group_file("tunnel", "horseshoe_wide"))


def _rig(name, safety, tunnel=None):
    return load_rig(name, tunnel or safety.tunnel, safety.distances, safety.points_per_capsule)


def _random_q(boom, n, seed):
    g = torch.Generator().manual_seed(seed)
    lo, hi = boom.limits(D)
    return lo + (hi - lo) * torch.rand(n, boom.n_joints, generator=g, dtype=D)


def test_single_reproduces_todays_clearances_exactly(safety, jumbo8):
    rig = _rig("single", safety)
    assert rig.names == ["B"] and rig.booms[0].base == (0.0, 0.0, 0.0)
    boom = rig.booms[0]
    q = _random_q(jumbo8, 500, 0)
    today, ours = safety.clearances(q), boom.safety.clearances_from_frames(boom.frames(q))
    assert all(torch.equal(today[k], ours[k]) for k in today)
    fast = boom.clearances(q)  # the compiled kernel (tests/test_compiled_rig.py): rounding level, same verdicts
    assert all((fast[k] - today[k]).abs().max() <= 1e-12 and torch.equal(fast[k] < 0, today[k] < 0) for k in today)
    (c0, g0), (c1, g1) = safety.clearances_with_jacobians(jumbo8.frames(q)), boom.clearances_with_jacobians(q)
    assert all(torch.equal(c0[k], c1[k]) and torch.equal(g0[k], g1[k]) for k in c0)
    assert torch.equal(torch.cat(jumbo8.tool_pose(q), -1), torch.cat(boom.tool_pose(q), -1))


def test_each_boom_sees_the_tunnel_from_its_base_by_hand(safety):
    """Home pose: the feed runs 0.8 m to the right of its boom (y - 0.8), both at z = 1.6. Wall
    clearance = 2.5 - |y| - radius - 0.5 of the capsule nearer the wall."""
    rig = _rig("twin", safety)
    q = torch.tensor(HOME, dtype=D)
    L, R = (rig.booms[rig.index(n)] for n in ("L", "R"))
    assert float(R.clearances(q)["wall"]) == pytest.approx(2.5 - 1.6 - 0.15 - 0.5, abs=1e-12)  # R's feed at y=-1.6
    assert float(L.clearances(q)["wall"]) == pytest.approx(2.5 - 0.8 - 0.20 - 0.5, abs=1e-12)  # L's boom at y=+0.8
    assert float(L.clearances(q)["self"]) == pytest.approx(float(safety.clearances(q)["self"]), abs=1e-12)
    p, _ = L.tool_pose(q)
    assert p.tolist() == pytest.approx([6.35, 0.0, 1.6], abs=1e-12)  # reference vector 1, moved by +0.8 in y


def test_mounted_clearance_gradients_match_autograd(safety):
    """The Jacobians of a boom off the centre line (translation leaves them unchanged) against autograd."""
    boom = _rig("twin", safety).booms[0]
    q = _random_q(boom.boom, 64, 1).requires_grad_(True)
    values, grads = boom.clearances_with_jacobians(q.detach())
    ref = boom.clearances(q)
    for k, v in ref.items():
        (g,) = torch.autograd.grad(v.sum(), q, retain_graph=True)
        assert torch.allclose(values[k], v.detach(), atol=1e-12, rtol=0)
        assert torch.allclose(grads[k], g, atol=1e-9, rtol=1e-9), k


def _brute_gap(a, qa, b, qb, n=801):
    """Smallest distance between sampled axis points of every capsule pair, less the radii."""
    best = math.inf
    s = torch.linspace(0, 1, n, dtype=D)[:, None]
    fa, fb = a.frames(qa), b.frames(qb)
    for ca in a.boom.bodies.values():
        pa0, pa1 = a.boom.capsule_ends(fa, ca.name)
        for cb in b.boom.bodies.values():
            pb0, pb1 = b.boom.capsule_ends(fb, cb.name)
            gap = torch.cdist(pa0 + s * (pa1 - pa0), pb0 + s * (pb1 - pb0)).min() - ca.radius - cb.radius
            best = min(best, float(gap))
    return best


def test_twin_parks_keep_d_boom_and_safety(safety):
    rig = _rig("twin", safety)
    assert rig.names == ["L", "R"] and rig.d_boom == 0.3
    assert [b.base for b in rig.booms] == [(0.0, 0.8, 0.0), (0.0, -0.8, 0.0)]
    L, R = rig.booms
    for b in rig.booms:
        assert all(float(v) >= 0 for v in b.clearances(b.park).values())
        assert bool(b.boom.within_limits(b.park))
    assert _brute_gap(L, L.park, R, R.park) >= 0.3
    assert float(rig.boom_clearance(0, L.park, 1, R.park)) >= 0
    assert float(rig.boom_clearance(1, R.park, 0, L.park)) == float(rig.boom_clearance(0, L.park, 1, R.park))
    # the feeds are stowed on the outer sides: L's at y = +1.6, R's at y = -1.6
    assert float(L.tool_pose(L.park)[0][1]) == pytest.approx(1.6, abs=1e-12)
    assert float(R.tool_pose(R.park)[0][1]) == pytest.approx(-1.6, abs=1e-12)


def test_rig_gradients_in_either_order(safety):
    rig = _rig("twin", safety)
    qa, qb = _random_q(rig.booms[0].boom, 20, 2), _random_q(rig.booms[1].boom, 20, 3)
    c01, ga, gb = rig.boom_clearance_with_jacobians(0, qa, 1, qb)
    c10, gb2, ga2 = rig.boom_clearance_with_jacobians(1, qb, 0, qa)
    assert torch.equal(c01, c10) and torch.equal(ga, ga2) and torch.equal(gb, gb2)


def test_trio_in_the_wide_drift(safety, wide):
    assert (wide.width, wide.wall_height, wide.crown) == (8.0, 3.0, 7.0)
    rig = _rig("trio", safety, wide)
    assert rig.names == ["L", "M", "R"] and [b.base[1] for b in rig.booms] == [1.6, 0.0, -1.6]
    for i in range(3):
        for j in range(i + 1, 3):
            a, b = rig.booms[i], rig.booms[j]
            assert _brute_gap(a, a.park, b, b.park) >= 0.3
    # selecting the rig selects its drift; an explicit tunnel choice still wins
    plus = "" if "rig" in compose() else "+"  # appended until conf/config.yaml lists the rig group
    assert compose([f"{plus}rig=trio"]).tunnel.width == 8.0
    assert compose([f"{plus}rig=trio", "tunnel=horseshoe"]).tunnel.width == 5.0
    assert compose([f"{plus}rig=twin"]).tunnel.width == 5.0


def test_trio_in_the_reference_drift_names_the_file_and_the_boom(safety):
    with pytest.raises(ConfigError, match=r"conf/rig/trio\.yaml: boom 'L'\.park.*wall"):
        _rig("trio", safety)


def _node(mounts=None, **changes):
    """twin.yaml with some of its booms' fields (``mounts``: index -> fields) or top fields changed."""
    node = load_group_file("rig", "twin")
    for i, entry in (mounts or {}).items():
        node["booms"][i].update(entry)
    node.update(changes)
    return node


BAD = {
    "unknown boom config": (_node({1: {"boom": "jumbo9"}}), r"bad\.yaml: boom 'R'\.boom = 'jumbo9'.*unknown boom"),
    "duplicate names": (_node({1: {"name": "L"}}), r"bad\.yaml: boom 'L': duplicate boom name"),
    "base outside": (_node({0: {"base": [0.0, 3.0, 0.0]}}), r"bad\.yaml: boom 'L'\.base.*outside the tunnel"),
    "base below the floor": (_node({1: {"base": [0.0, 0.0, -0.5]}}), r"bad\.yaml: boom 'R'\.base.*outside"),
    "overlap at park": (_node({0: {"base": [0.0, 0.3, 0.0]}, 1: {"base": [0.0, -0.3, 0.0]}}),
                        r"bad\.yaml: boom 'L' and boom 'R' overlap at park.*0\.200 m apart.*d_boom = 0\.3"),
    "park out of range": (_node({1: {"park": [0, 0, 2.0, 0, 0, 0, 0, 1.0]}}),
                          r"bad\.yaml: boom 'R'\.park.*\['q3'\] outside the range"),
    "park length": (_node({1: {"park": [0, 0, 3.0]}}), r"bad\.yaml: boom 'R'\.park.*expected 8 values"),
    "park breaks the wall": (_node({0: {"park": [0, 0, 3.0, 0, 0, 45, 180, 1.0]}}),
                             r"bad\.yaml: boom 'L'\.park.*breaks safety"),
    "unknown field": (_node({0: {"yaw": 10}}), r"bad\.yaml: boom 'L'\.yaw: unknown setting"),
    "bad base": (_node({0: {"base": [0.0, 0.8]}}), r"bad\.yaml: boom 'L'\.base.*expected \[x, y, z\]"),
    "no booms": (_node(booms=[]), r"bad\.yaml: booms = \[\]"),
    "negative d_boom": (_node(d_boom=-1), r"bad\.yaml: rig\.d_boom = -1"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_rig_files_name_the_file_and_the_boom(case, safety):
    node, message = BAD[case]
    with pytest.raises(ConfigError, match=message):
        spec = parse_rig(node, "conf/rig/bad.yaml")
        build_rig(spec, rig_booms(spec), safety.tunnel, safety.distances, safety.points_per_capsule)


def test_every_rig_file_parses():
    for name in ("single", "twin", "trio"):
        spec = rig_spec(name)
        assert spec.name == name and spec.source == f"conf/rig/{name}.yaml"
        assert all(m.boom == "jumbo8" for m in spec.mounts)
