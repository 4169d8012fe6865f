"""The label-consistency measure (pipeline/data/consistency.py) on sets whose branches are known by
construction: a planar two-link arm, whose every reachable point has an elbow-up and an elbow-down
solution, and jumbo8's supervised sets."""

import math

import pytest
import torch

from pipeline.core.errors import InputError
from pipeline.data.consistency import label_consistency
from pipeline.data.couplings import parse_couplings, sample_coupled_joints
from pipeline.data.hole_sets import set_consistency
from pipeline.data.holes import sample_joints
from pipeline.data.neighbours import nearest_neighbours

L1, L2 = 1.0, 0.7
SCALE = torch.tensor([2 * math.pi, 2 * math.pi], dtype=torch.float64)


def arm(q: torch.Tensor) -> torch.Tensor:
    """The planar arm's hand position (the pose map)."""
    a, b = q[:, 0], q[:, 0] + q[:, 1]
    return torch.stack([L1 * torch.cos(a) + L2 * torch.cos(b), L1 * torch.sin(a) + L2 * torch.sin(b)], dim=-1)


def other_elbow(q: torch.Tensor) -> torch.Tensor:
    """The other solution of the same hand position: the elbow mirrored about the shoulder-hand line."""
    q2 = q[:, 1]
    shift = 2 * torch.atan2(L2 * torch.sin(q2), L1 + L2 * torch.cos(q2))
    return torch.stack([q[:, 0] + shift, -q2], dim=-1)


@pytest.fixture(scope="module")
def elbow_up():
    gen = torch.Generator().manual_seed(0)
    n = 4000
    q = torch.stack([torch.rand(n, generator=gen, dtype=torch.float64) * 1.5 - 0.75,  # shoulder
                     torch.rand(n, generator=gen, dtype=torch.float64) * 2.0 + 0.5],  # elbow up, away from 0 and pi
                    dim=-1)
    return q


def test_the_other_elbow_reaches_the_same_point(elbow_up):
    assert torch.allclose(arm(other_elbow(elbow_up)), arm(elbow_up), atol=1e-12)


def test_mixed_branches_score_worse_than_one_branch(elbow_up):
    pose = arm(elbow_up)
    flip = torch.rand(len(pose), generator=torch.Generator().manual_seed(1)) < 0.5
    mixed = torch.where(flip[:, None], other_elbow(elbow_up), elbow_up)
    assert torch.allclose(arm(mixed), pose, atol=1e-12)  # same poses, other labels
    one = label_consistency(pose, elbow_up, SCALE, arm, queries=4000)
    two = label_consistency(pose, mixed, SCALE, arm, queries=4000)
    # one smooth branch: no pair jumps; half the samples flipped: a pair jumps when exactly one of
    # its two samples is flipped, i.e. for about 2 * 0.5 * 0.5 of the pairs
    assert one["branch_jump_share"] < 0.01
    assert 0.45 < two["branch_jump_share"] < 0.55
    assert two["ratio_p95"] > 5 * one["ratio_p95"]
    assert one["pairs"] == two["pairs"] == 4000


def test_the_measure_does_not_depend_on_the_order_of_the_samples_and_leaves_its_inputs(elbow_up):
    pose, q = arm(elbow_up), elbow_up.clone()
    perm = torch.randperm(len(q), generator=torch.Generator().manual_seed(2))
    a = label_consistency(pose, q, SCALE, arm, queries=len(q))
    b = label_consistency(pose[perm], q[perm], SCALE, arm, queries=len(q))
    assert a == pytest.approx(b)
    assert torch.equal(q, elbow_up) and torch.equal(pose, arm(elbow_up))


def test_nearest_neighbours_are_exact_and_never_the_point_itself():
    gen = torch.Generator().manual_seed(3)
    points = torch.rand(700, 3, generator=gen, dtype=torch.float64)
    query = torch.arange(0, 700, 7)
    idx, dist = nearest_neighbours(points, query, chunk=16)
    full = torch.cdist(points[query], points)
    full[torch.arange(len(query)), query] = math.inf
    assert torch.equal(idx, full.argmin(dim=1)) and torch.allclose(dist, full.min(dim=1).values)
    assert not bool((idx == query).any())
    idx3, dist3 = nearest_neighbours(points, query, k=3, chunk=16)
    assert torch.equal(idx3[:, 0], idx) and bool((dist3[:, 1:] >= dist3[:, :-1]).all())


def test_jumbo8_labels_on_the_couplings_are_more_consistent_than_labels_on_all_eight_joints(jumbo8):
    """On all 8 joints a hole pose has a 3-parameter family of solutions, on paper 000's couplings a
    1-parameter one: fewer pairs of neighbours can land on different branches."""
    box = {"q1": [-17, 28], "q2": [-9, 38], "q4": [-57, 73], "q5": [-42, 20], "q6": [-27, 34], "q7": [-79, 86]}
    couplings = parse_couplings([{"coeffs": {"q2": 1, "q5": 1}, "value": 0},
                                 {"coeffs": {"q1": 1, "q6": -1}, "value": 0}], jumbo8.joint_names)
    free = sample_joints(5000, jumbo8, 0, box)
    coupled = sample_coupled_joints(5000, jumbo8, 0, box, couplings)
    free_c = set_consistency(jumbo8, jumbo8.pose6(free), free)
    coupled_c = set_consistency(jumbo8, jumbo8.pose6(coupled), coupled)
    assert coupled_c["branch_jump_share"] < free_c["branch_jump_share"]


@pytest.mark.parametrize("pose, q, scale, match", [
    (torch.zeros(5, 2), torch.zeros(4, 2), SCALE, "same n"),
    (torch.zeros(1, 2), torch.zeros(1, 2), SCALE, "at least 2"),
    (torch.rand(5, 2), torch.rand(5, 2), torch.tensor([1.0, 0.0]), "one positive number per joint"),
    (torch.zeros(5, 2), torch.rand(5, 2), SCALE, "every pair repeats one pose"),
])
def test_bad_input_is_refused_with_the_problem_named(pose, q, scale, match):
    with pytest.raises(InputError, match=match):
        label_consistency(pose.double(), q.double(), scale.double(), arm)
