"""Labels by continuation (pipeline/solvers/continuation.py) on a planar two-link arm, whose every
point has an elbow-up and an elbow-down solution: the walk keeps the seeds' branch."""

import math

import torch

from pipeline.solvers.continuation import continuation_labels

L1, L2 = 1.0, 0.7


def arm(q):
    a, b = q[:, 0], q[:, 0] + q[:, 1]
    return torch.stack([L1 * torch.cos(a) + L2 * torch.cos(b), L1 * torch.sin(a) + L2 * torch.sin(b)], dim=-1)


def both_elbows(p):
    """The two exact solutions of each point (elbow up: q2 > 0)."""
    c2 = ((p ** 2).sum(-1) - L1 ** 2 - L2 ** 2) / (2 * L1 * L2)
    out = []
    for sign in (1.0, -1.0):
        q2 = sign * torch.arccos(c2.clamp(-1, 1))
        q1 = torch.atan2(p[:, 1], p[:, 0]) - torch.atan2(L2 * torch.sin(q2), L1 + L2 * torch.cos(q2))
        out.append(torch.stack([q1, q2], dim=-1))
    return out


def nearest_solution(start, p):
    """A local solver: of the two solutions, the one nearest the start (as a descent from it would end)."""
    up, down = both_elbows(p)
    pick_up = (up - start).norm(dim=-1) <= (down - start).norm(dim=-1)
    return torch.where(pick_up[:, None], up, down), torch.ones(len(p), dtype=torch.bool)


def points(n=3000, seed=0):
    gen = torch.Generator().manual_seed(seed)
    q = torch.stack([torch.rand(n, generator=gen, dtype=torch.float64) * 1.5 - 0.75,
                     torch.rand(n, generator=gen, dtype=torch.float64) * 2.0 + 0.5], dim=-1)
    return arm(q)


def test_the_walk_labels_every_point_on_its_seeds_branch():
    p = points()
    q0 = torch.zeros(len(p), 2, dtype=torch.float64)
    solved0 = torch.zeros(len(p), dtype=torch.bool)
    up, _ = both_elbows(p[:1])
    q0[0], solved0[0] = up[0], True  # one seed, elbow up
    q0_before, solved0_before = q0.clone(), solved0.clone()
    q, exact, stats = continuation_labels(p, nearest_solution, q0, solved0, neighbours=6)
    assert bool(exact.all()) and stats["solved_share"] == 1.0 and stats["waves"] > 3
    assert torch.allclose(arm(q), p, atol=1e-9)
    assert bool((q[:, 1] > 0).all())  # one branch everywhere: no point flipped to elbow down
    assert torch.equal(q0, q0_before) and torch.equal(solved0, solved0_before)  # inputs untouched


def test_a_point_that_never_solves_is_tried_a_bounded_number_of_times_and_reported():
    p = points(500, seed=1)
    bad = p[:, 0] > 1.2  # a region the solver never reaches
    calls = []

    def refine(start, target):
        q, _ = nearest_solution(start, target)
        calls.append(len(target))
        return q, ~(target[:, 0] > 1.2)

    q0 = torch.zeros(len(p), 2, dtype=torch.float64)
    solved0 = ~bad & (torch.arange(len(p)) % 50 == 0)
    _, exact, stats = continuation_labels(p, refine, q0, solved0, neighbours=6, max_tries=2)
    assert not bool(exact[bad].any())
    assert stats["solved_share"] == float(exact.double().mean())
    assert sum(calls) <= int((~solved0).sum()) * 2  # each unsolved point refined at most max_tries times
    assert math.isclose(stats["seeded_share"], float(solved0.double().mean()))


def test_a_longer_budget_labels_the_arch_holes_a_short_one_misses_on_one_branch(safety):
    """On jumbo8, the descent towards a hole high in the arch meets the boom extension's limit and
    needs more than the local search's 12 iterations to slide along the redundancy; with a longer
    budget those holes get labels, exact by forward kinematics, without labels jumping branches."""
    from pipeline.assembly.build import hole_sampling
    from pipeline.core.config import compose
    from pipeline.data.hole_sets import set_consistency
    from pipeline.data.holes import sample_holes
    from pipeline.solvers.labels import LOCAL_SEARCH, continuation

    pose, _ = sample_holes(2000, safety, hole_sampling(compose([]).holes), 4)
    label = continuation(safety)
    _, short = label(pose, None)
    q, long = label(pose, 200)
    assert float(long.double().mean()) > float(short.double().mean()) + 0.05
    assert float(pose[~short, 2].mean()) > float(pose[:, 2].mean()) + 1.0  # the misses lie high, in the arch
    err = 0.5 * ((safety.boom.pose6(q[long]) - pose[long]).reshape(-1, 2, 3).norm(dim=-1)).sum(-1)
    assert float(err.max()) <= LOCAL_SEARCH.tol_mm / 1000
    assert set_consistency(safety.boom, pose[long], q[long])["branch_jump_share"] <= 0.02
