"""Joints on linear couplings (pipeline/data/couplings.py): paper 000's pair in jumbo8's zeros, the
sampler, and the config's copies of the rows."""

import pytest
import torch

from pipeline.core.config import as_dict, compose
from pipeline.core.errors import ConfigError
from pipeline.data.couplings import parse_couplings, sample_coupled_joints
from pipeline.data.holes import joint_box

PAPER = [{"coeffs": {"q2": 1, "q5": 1}, "value": 0}, {"coeffs": {"q1": 1, "q6": -1}, "value": 0}]
BOX = {"q1": [-17, 28], "q2": [-9, 38], "q4": [-57, 73], "q5": [-42, 20], "q6": [-27, 34], "q7": [-79, 86]}


def feed_direction(boom, q):
    pose = boom.pose6(q)
    d = pose[:, 3:] - pose[:, :3]
    return d / d.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("signs, parallel", [((1, -1), True), ((1, 1), False), ((-1, -1), False), ((-1, 1), False)])
def test_paper_couplings_in_jumbo8_zeros_hold_the_feed_parallel_to_x(jumbo8, signs, parallel):
    """q2 + q5 = 0 and q1 - q6 = 0, with the boom rotation and roll-over at 0: the feed points along +x
    whatever the lift, swing and extensions; flip either sign and it does not."""
    rows = [{"coeffs": {"q2": 1, "q5": signs[0]}, "value": 0}, {"coeffs": {"q1": 1, "q6": signs[1]}, "value": 0}]
    box = {**BOX, "q4": [-1e-6, 1e-6], "q7": [-1e-6, 1e-6]}
    q = sample_coupled_joints(2000, jumbo8, 0, box, parse_couplings(rows, jumbo8.joint_names))
    x = torch.tensor([1.0, 0, 0], dtype=q.dtype)
    off = (feed_direction(jumbo8, q) - x).norm(dim=-1)
    if parallel:
        assert float(off.max()) < 1e-5
    else:
        assert float(off.max()) > 0.05


def test_samples_lie_on_the_couplings_and_in_the_box(jumbo8):
    couplings = parse_couplings(PAPER, jumbo8.joint_names)
    assert couplings.dependent == (4, 5)  # q5 and q6: the feed joints compensate
    q = sample_coupled_joints(3000, jumbo8, 5, BOX, couplings)
    lo, hi = joint_box(jumbo8, BOX)
    assert q.shape == (3000, 8)
    assert float(couplings.residual(q).abs().max()) < 1e-12
    assert bool(((q >= lo - 1e-12) & (q <= hi + 1e-12)).all())
    # the free joints fill their ranges (not squeezed by the couplings)
    edge = 0.05 * (hi - lo)
    for i in (2, 3, 6, 7):
        assert float(q[:, i].min()) < lo[i] + edge[i] and float(q[:, i].max()) > hi[i] - edge[i]
    assert torch.equal(q, sample_coupled_joints(3000, jumbo8, 5, BOX, couplings))  # seeded


def test_a_dependent_joint_outside_the_box_is_rejected_not_clamped(jumbo8):
    """q6 = q1: with q1 over [-17, 28] deg and q6 only over [0, 34], about 17 / 45 of the draws fall out."""
    box = {**BOX, "q6": [0, 34]}
    q = sample_coupled_joints(2000, jumbo8, 1, box, parse_couplings(PAPER, jumbo8.joint_names))
    assert float(q[:, 5].min()) >= -1e-12 and float(q[:, 0].min()) >= -1e-12  # q1 = q6 >= 0 too


def test_the_study_and_the_benchmark_share_the_couplings():
    cfg = compose()
    study = as_dict(cfg.holes.sup_variants.coupled)["couplings"]
    assert study == as_dict(cfg.solver_benchmark.solvers.nm_coupled)["couplings"]


@pytest.mark.parametrize("rows, match", [
    ([], "expected a non-empty list"),
    ([{"coeffs": {"q9": 1}}], r"'q9' is not a joint"),
    ([{"coeffs": {"q1": "a"}}], r"coeffs.q1 = 'a': expected a number"),
    ([{"coeffs": {"q1": 1}, "value": "x"}], r"value = 'x': expected a number"),
    ([{"coef": {"q1": 1}}], r"expected \{coeffs"),
    ([{"coeffs": {"q1": 1}}, {"coeffs": {"q1": 2}}], "already solved for by an earlier row"),
])
def test_bad_rows_are_refused_with_the_row_named(jumbo8, rows, match):
    with pytest.raises(ConfigError, match=match):
        parse_couplings(rows, jumbo8.joint_names, "holes.sup_variants.coupled.couplings")


def test_couplings_the_box_cannot_meet_fail_with_the_joints_named(jumbo8):
    rows = [{"coeffs": {"q1": 1, "q6": -1}, "value": 1.2}]  # q6 = q1 - 1.2 rad: below q6's box everywhere
    with pytest.raises(ConfigError, match=r"dependent joints \['q6'\] within the box"):
        sample_coupled_joints(100, jumbo8, 0, BOX, parse_couplings(rows, jumbo8.joint_names), max_batches=3)
