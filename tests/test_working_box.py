"""Omega_sup from the working box (docs/reference.md, section 3): samples in the box, poses by forward kinematics,
face-like enough; the box derivation is reproducible; bad boxes are named."""

import math

import pytest
import torch

from pipeline import generate
from pipeline.core.errors import ConfigError, InputError
from pipeline.data.hole_sets import read_hole_table
from pipeline.data.holes import HoleSampling, in_face_window, joint_box, sample_joints
from pipeline.data.tables import POSE_COLUMNS
from pipeline.learning.supervised_set import derive_working_box
from pipeline.solvers.labels import local_search


@pytest.fixture(scope="module")
def sup(tmp_path_factory, copy_tiny_study, make_cfg):
    """Omega_sup of the tiny study (generated once per session), drawn in the working box."""
    tmp = copy_tiny_study(tmp_path_factory.mktemp("sup"))
    return read_hole_table(tmp / "data" / "holes", "sup.parquet"), make_cfg(tmp)


def test_every_sample_lies_in_the_box_and_its_pose_is_its_forward_kinematics(sup, jumbo8):
    df, cfg = sup
    lo, hi = joint_box(jumbo8, dict(cfg.holes.sup.box))
    q = torch.tensor(df[jumbo8.joint_names].to_numpy())
    assert ((q >= lo) & (q <= hi)).all()
    assert torch.allclose(jumbo8.pose6(q), torch.tensor(df[POSE_COLUMNS].to_numpy()), atol=1e-12)
    # the box is narrower than the mechanical ranges where it matters (boom rotation, roll-over)
    full_lo, full_hi = jumbo8.limits()
    assert ((hi - lo)[[3, 6]] < 0.6 * (full_hi - full_lo)[[3, 6]]).all()


def test_at_least_a_third_of_the_collars_are_face_like_against_a_few_percent_for_full_ranges(sup, safety):
    df, _ = sup
    share = in_face_window(torch.tensor(df[POSE_COLUMNS].to_numpy()), safety.tunnel).double().mean()
    assert share >= 1 / 3
    full = safety.boom.pose6(sample_joints(3000, safety.boom, seed=1))
    assert in_face_window(full, safety.tunnel).double().mean() < 0.06


def test_the_face_window_test_itself():
    tunnel = __import__("pipeline.geometry.tunnel", fromlist=["Horseshoe"]).Horseshoe()
    pose = torch.tensor([[6.5, 0, 1.6, 9.8, 0, 1.6],               # straight at the face
                         [6.5, 0, 1.6, 6.5, 0, 4.9],               # pointing up: 90 deg off
                         [4.0, 0, 1.6, 7.3, 0, 1.6],               # collar short of the window
                         [6.5, 3.0, 1.6, 9.8, 3.0, 1.6]], dtype=torch.float64)  # collar outside the profile
    assert in_face_window(pose, tunnel).tolist() == [True, False, False, False]


def test_the_box_derivation_is_deterministic_for_a_seed(safety):
    a, sa = derive_working_box(safety, HoleSampling(), 150, seed=7, solve=local_search(safety))
    b, _ = derive_working_box(safety, HoleSampling(), 150, seed=7, solve=local_search(safety))
    c, _ = derive_working_box(safety, HoleSampling(), 150, seed=8, solve=local_search(safety))
    assert a == b and a != c
    assert sa["ok"] >= 130 and set(a) == set(safety.boom.joint_names)


@pytest.mark.parametrize(("box", "pattern"), [
    ({"q2": [-40, 30]}, r"holes.sup.box.q2 = \[-40, 30\] deg: outside the joint's range \[-30.0, 65.0\]"),
    ({"q3": [2.0, 4.0]}, r"holes.sup.box.q3 = \[2.0, 4.0\] m: outside the joint's range"),
    ({"q1": [10, 10]}, r"holes.sup.box.q1 = \[10, 10\]: empty box"),
    ({"q1": [20, -5]}, r"empty box"),
    ({"q9": [0, 1]}, r"unknown joint\(s\) \['q9'\]"),
    ({"q1": [0, math.nan]}, r"holes.sup.box.q1 = .*expected \[lower, upper\] in deg"),
])
def test_a_bad_box_is_named(jumbo8, box, pattern):
    with pytest.raises(ConfigError, match=pattern):
        joint_box(jumbo8, box)


def test_generate_refuses_a_bad_box_before_writing(tmp_path, make_cfg):
    with pytest.raises(ConfigError, match="empty box"):
        generate.run(make_cfg(tmp_path, "holes.sup.box.q1=[5,5]"))
    assert not (tmp_path / "data").exists()


@pytest.mark.slow
def test_full_ranges_stay_available(tmp_path, make_cfg):
    cfg = make_cfg(tmp_path, "sup_box=full", "holes.sup.size=500", "holes.unsup.size=200", "holes.test.size=20")
    assert cfg.holes.sup.box is None
    meta = generate.run(cfg)
    assert meta["sup_box"] is None and meta["sup_sets"]["sup"]["face_window_share"] < 0.06


def test_too_few_solved_holes_is_an_error(safety):
    with pytest.raises(InputError, match="too few"):
        derive_working_box(safety, HoleSampling(), 50, seed=1, solve=local_search(safety))
