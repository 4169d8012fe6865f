"""Forward kinematics against the reference's test vectors and independent checks."""

import copy
import math

import pytest
import torch

from pipeline.assembly.build import load_boom
from pipeline.core.config import load_group_file
from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.boom_config import boom_from_config
from pipeline.geometry.kinematics import pose_errors

r = math.radians

# Spec section 1. The q column there is printed to 6 decimals; it is these exact degrees.
JUMBO8_VECTORS = [
    ([0, 0, 3.5, 0, 0, 0, 0, 2.5], [6.35, -0.8, 1.6, 9.65, -0.8, 1.6]),
    (
        [r(10), r(15), 4.0, r(30), r(-20), r(10), r(45), 2.0],
        [6.046605, 0.865722, 1.623475, 9.259662, 1.492682, 1.207315],
    ),
    (
        [r(-30), r(40), 3.2, r(-120), r(35), r(-50), r(-90), 3.1],
        [5.034832, -2.479663, 2.146972, 7.639759, -4.226459, 1.120783],
    ),
]


def test_jumbo8_test_vectors(jumbo8):
    q = torch.tensor([v[0] for v in JUMBO8_VECTORS], dtype=torch.float64)
    expected = torch.tensor([v[1] for v in JUMBO8_VECTORS], dtype=torch.float64)
    assert torch.allclose(jumbo8.pose6(q), expected, atol=1e-6, rtol=0)


def test_jumbo8_printed_q_column_agrees_to_rounding(jumbo8):
    # The 6-decimal q of the reference moves the pose by at most a few micrometres.
    q = torch.tensor([[0.174533, 0.261799, 4.0, 0.523599, -0.349066, 0.174533, 0.785398, 2.0]], dtype=torch.float64)
    expected = torch.tensor([JUMBO8_VECTORS[1][1]], dtype=torch.float64)
    assert torch.allclose(jumbo8.pose6(q), expected, atol=1e-5, rtol=0)


def test_huang9_all_zero():
    boom = load_boom("huang9")
    p, _ = boom.tool_pose(torch.zeros(8, dtype=torch.float64))
    assert torch.allclose(p * 1000, torch.tensor([5793.0, -2060.0, 206.0], dtype=torch.float64), atol=1e-3)


def test_rescue6_theta6_30deg():
    boom = load_boom("rescue6")
    p, _ = boom.tool_pose(torch.tensor([0, 0, 0, 0, 0, r(30)], dtype=torch.float64))
    assert torch.allclose(p * 1000, torch.tensor([1091.77, 0.0, 180.0], dtype=torch.float64), atol=5e-3)


def test_huang9_l1_extends_row2_link():
    """L1 adds to row 2's a: the same as a boom whose table has a = 3978 + L1 and L1 locked."""
    cfg = load_group_file("boom", "huang9")
    cfg["joints"][6]["locked"] = None
    boom = boom_from_config(cfg)
    stretched = copy.deepcopy(cfg)
    stretched["dh"][1]["a"] = 3978 + 700
    fixed = boom_from_config(stretched)
    q = torch.tensor([0.1, -0.4, 0.3, 0.2, -0.5, 0.6, 0.0, 1.2], dtype=torch.float64)
    q_l1 = q.clone()
    q_l1[6] = 0.7
    assert torch.allclose(boom.frames(q_l1), fixed.frames(q), atol=1e-12)


def _standard_as_modified(cfg):
    """Rewrite a standard D-H chain in the modified convention.

    prod_i RotZ(th_i) TransZ(d_i) TransX(a_i) RotX(al_i) equals the modified chain whose row k
    carries (alpha, a) = (al_{k-1}, a_{k-1}) with (al_0, a_0) = 0, plus a final row (al_n, a_n);
    TransX and RotX commute, so only the grouping changes.
    """
    out = copy.deepcopy(cfg)
    rows = cfg["dh"]
    out["convention"] = "modified"
    out["dh"] = [
        {"alpha": rows[i - 1]["alpha"] if i else 0, "a": rows[i - 1]["a"] if i else 0,
         "theta": rows[i]["theta"], "d": rows[i]["d"]}
        for i in range(len(rows))
    ] + [{"alpha": rows[-1]["alpha"], "a": rows[-1]["a"], "theta": 0, "d": 0}]
    for joint in out["joints"]:
        if joint["param"] == "a":  # a link extension moves to the next row in the modified table
            joint["row"] += 1
        joint["locked"] = None
    return out


@pytest.mark.parametrize("name", ["huang9", "rescue6"])
def test_standard_equals_modified_rewrite(name):
    cfg = load_group_file("boom", name)
    for joint in cfg["joints"]:
        joint["locked"] = None
    std = boom_from_config(cfg)
    mod = boom_from_config(_standard_as_modified(cfg))
    gen = torch.Generator().manual_seed(0)
    lo, hi = std.limits()
    q = lo + torch.rand(64, std.n_joints, generator=gen, dtype=torch.float64) * (hi - lo)
    ps, zs = std.tool_pose(q)
    pm, zm = mod.tool_pose(q)
    assert torch.allclose(ps, pm, atol=1e-9) and torch.allclose(zs, zm, atol=1e-12)


def test_frames_every_frame_and_batch_shapes(jumbo8):
    q = torch.tensor(JUMBO8_VECTORS[1][0], dtype=torch.float64)
    frames = jumbo8.frames(q.expand(2, 3, 8))
    assert frames.shape == (2, 3, jumbo8.n_rows + 2, 4, 4)
    assert torch.equal(frames[..., 0, :, :], torch.eye(4, dtype=torch.float64).expand(2, 3, 4, 4))
    # frame k = frame k-1 @ link k, for every k
    links = jumbo8.link_transforms(q)
    single = jumbo8.frames(q)
    for k in range(1, jumbo8.n_rows + 1):
        assert torch.allclose(single[k], single[k - 1] @ links[k - 1], atol=1e-12)
    assert torch.allclose(frames[1, 2], single)
    # rotations stay orthonormal
    rot = single[:, :3, :3]
    assert torch.allclose(rot @ rot.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand_as(rot), atol=1e-12)


def test_float32_matches_float64(jumbo8):
    q = torch.tensor([v[0] for v in JUMBO8_VECTORS], dtype=torch.float64)
    assert jumbo8.pose6(q.float()).dtype == torch.float32
    assert torch.allclose(jumbo8.pose6(q.float()).double(), jumbo8.pose6(q), atol=5e-6)


def test_autograd_jacobian_matches_finite_differences(jumbo8):
    q0 = torch.tensor(JUMBO8_VECTORS[2][0], dtype=torch.float64)
    jac = torch.autograd.functional.jacobian(jumbo8.pose6, q0)
    h = 1e-6
    fd = torch.stack(
        [(jumbo8.pose6(q0 + h * e) - jumbo8.pose6(q0 - h * e)) / (2 * h) for e in torch.eye(8, dtype=torch.float64)],
        dim=-1,
    )
    assert torch.allclose(jac, fd, atol=1e-7)


def test_limits_and_locks():
    boom = load_boom("huang9")
    lo, hi = boom.limits()
    assert lo[6] == hi[6] == 0.0  # L1 locked at 0
    assert math.isclose(float(hi[7]), 2.0) and math.isclose(float(lo[0]), -math.pi)
    q = torch.ones(3, 8, dtype=torch.float64)
    assert not boom.within_limits(q).any()
    assert boom.within_limits(boom.with_locks(q)).all()


def test_pose_errors_known_offsets():
    target = torch.tensor([[6.0, 0.0, 1.0, 9.3, 0.0, 1.0]], dtype=torch.float64)
    shifted = target + torch.tensor([[0.003, 0.004, 0.0, 0.003, 0.004, 0.0]], dtype=torch.float64)
    err = pose_errors(shifted, target)
    assert torch.allclose(err["start"], torch.tensor([0.005], dtype=torch.float64))
    assert torch.allclose(err["hole"], torch.tensor([0.005], dtype=torch.float64))
    assert float(err["direction"]) == pytest.approx(0.0, abs=1e-12)
    tilted = target.clone()
    tilted[0, 4] += 3.3 * math.tan(r(2))
    assert float(pose_errors(tilted, target)["direction"]) == pytest.approx(r(2), rel=1e-9)


# ---------------------------------------------------------------- errors that help
def test_unknown_boom_names_the_options():
    with pytest.raises(ConfigError, match=r"unknown boom 'jumbo9'.*jumbo8"):
        load_boom("jumbo9")


def test_dh_row_missing_column():
    cfg = load_group_file("boom", "jumbo8")
    del cfg["dh"][3]["alpha"]
    with pytest.raises(ConfigError, match=r"dh row 4: missing required field 'alpha'"):
        boom_from_config(cfg)


@pytest.mark.parametrize(
    ("path", "value", "pattern"),
    [
        (("convention",), "craig", r"convention = 'craig'"),
        (("joints", 2, "param"), "alpha", r"joint 'q3'.param = 'alpha'"),
        (("joints", 0, "range"), [45, -45], r"joint 'q1'.range = \[45, -45\]"),
        (("dh", 1, "a"), "wide", r"dh row 2.a = 'wide'"),
        (("joints", 0, "row"), 9, r"joint 'q1'.row = 9"),
    ],
)
def test_bad_boom_fields(path, value, pattern):
    cfg = load_group_file("boom", "jumbo8")
    node = cfg
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ConfigError, match=pattern):
        boom_from_config(cfg)


def test_joint_vector_of_wrong_length(jumbo8):
    with pytest.raises(InputError, match=r"length 7 .*jumbo8.* 8 joints"):
        jumbo8.pose6(torch.zeros(5, 7))
    with pytest.raises(InputError, match="floating-point"):
        jumbo8.pose6(torch.zeros(5, 8, dtype=torch.long))
