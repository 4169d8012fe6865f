"""Boom-boom clearance: against brute-force sampling of both capsules, and its gradients against
autograd and finite differences."""


import pytest
import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.boom_pair import BoomPair

D = torch.float64


def _shift(frames, base):
    """Frames moved into the rig frame by a base translation (independent of MountedBoom.to_rig)."""
    out = frames.clone()
    out[..., :3, 3] += torch.tensor(base, dtype=frames.dtype)
    return out


def _random_q(boom, n, gen):
    lo, hi = boom.limits(D)
    return lo + (hi - lo) * torch.rand(n, boom.n_joints, generator=gen, dtype=D)


def _pair_frames(jumbo8, n, seed, y=0.8):
    """Two jumbo8 booms at y = +y and -y with random joints: many pairs far apart, some crossing."""
    g = torch.Generator().manual_seed(seed)
    qa, qb = _random_q(jumbo8, n, g), _random_q(jumbo8, n, g)
    return qa, qb, _shift(jumbo8.frames(qa), (0.0, y, 0.0)), _shift(jumbo8.frames(qb), (0.0, -y, 0.0))


def _capsules(boom, frames):
    """Axis ends (bodies, 2, 3) and radii, read from the config's bodies through Boom.capsule_ends."""
    ends = torch.stack([torch.stack(boom.capsule_ends(frames, n)) for n in boom.bodies])
    return ends, [b.radius for b in boom.bodies.values()]


def test_distances_match_brute_force_sampling(jumbo8):
    """Every capsule pair: the smallest distance between 1001 points sampled on each axis, less both
    radii, is never below the computed distance and at most half the two sample spacings above it."""
    pair = BoomPair(jumbo8, jumbo8, 0.3)
    n_pts = 1001
    s = torch.linspace(0, 1, n_pts, dtype=D)[:, None]
    checked = near = 0
    for seed, y in ((0, 0.8), (1, 0.4), (2, 0.15)):
        _, _, fa, fb = _pair_frames(jumbo8, 12, seed, y)
        d = pair.distances(fa, fb)
        for k in range(fa.shape[0]):
            ea, ra = _capsules(jumbo8, fa[k])
            eb, rb = _capsules(jumbo8, fb[k])
            for i in range(len(ra)):
                pa = ea[i, 0] + s * (ea[i, 1] - ea[i, 0])
                ha = float(torch.linalg.vector_norm(ea[i, 1] - ea[i, 0])) / (n_pts - 1)
                for j in range(len(rb)):
                    pb = eb[j, 0] + s * (eb[j, 1] - eb[j, 0])
                    hb = float(torch.linalg.vector_norm(eb[j, 1] - eb[j, 0])) / (n_pts - 1)
                    brute = float(torch.cdist(pa, pb).min()) - ra[i] - rb[j]
                    ours = float(d[k, i, j])
                    assert ours <= brute + 1e-12
                    assert brute - ours <= 0.5 * (ha + hb) + 1e-12
                    checked += 1
                    near += ours < 0.5
    assert checked == 3 * 12 * 4 and near >= 5  # the near cases (booms crossing) are exercised


def test_clearance_is_smallest_distance_less_d_boom(jumbo8):
    pair = BoomPair(jumbo8, jumbo8, 0.3)
    _, _, fa, fb = _pair_frames(jumbo8, 50, 3, 0.4)
    d = pair.distances(fa, fb)
    assert d.shape == (50, 2, 2)
    c = pair.clearance(fa, fb)
    assert torch.equal(c, d.flatten(-2).amin(-1) - 0.3)
    assert (c < 0).any() and (c > 0).any()  # both verdicts occur in this sample


def test_swapping_the_booms_transposes_the_distances(jumbo8):
    pair = BoomPair(jumbo8, jumbo8)
    _, _, fa, fb = _pair_frames(jumbo8, 30, 4, 0.4)
    assert torch.allclose(pair.distances(fa, fb), pair.distances(fb, fa).transpose(-1, -2), atol=1e-12, rtol=0)


def test_batches_broadcast_to_every_pairing(jumbo8):
    """(N, 1, ...) against (1, M, ...) gives the N x M table of single evaluations."""
    pair = BoomPair(jumbo8, jumbo8)
    _, _, fa, fb = _pair_frames(jumbo8, 5, 5, 0.4)
    table = pair.clearance(fa[:, None], fb[None, :])
    assert table.shape == (5, 5)
    for i in range(5):
        for j in range(5):
            assert float(table[i, j]) == pytest.approx(float(pair.clearance(fa[i], fb[j])), abs=1e-12)
    c, ga, gb = pair.clearance_with_jacobians(fa[:, None], fb[None, :])
    assert c.shape == (5, 5) and ga.shape == (5, 5, 8) and gb.shape == (5, 5, 8)
    c1, ga1, gb1 = pair.clearance_with_jacobians(fa[2], fb[3])
    assert torch.allclose(ga[2, 3], ga1, atol=1e-12) and torch.allclose(gb[2, 3], gb1, atol=1e-12)


def _autograd_grads(jumbo8, pair, qa, qb, ya, yb):
    qa, qb = qa.clone().requires_grad_(True), qb.clone().requires_grad_(True)
    c = pair.clearance(_shift(jumbo8.frames(qa), (0.0, ya, 0.0)), _shift(jumbo8.frames(qb), (0.0, yb, 0.0)))
    ga, gb = torch.autograd.grad(c.sum(), (qa, qb))
    return c.detach(), ga, gb


def test_clearance_gradients_match_autograd(jumbo8):
    pair = BoomPair(jumbo8, jumbo8, 0.3)
    qa, qb, fa, fb = _pair_frames(jumbo8, 200, 6, 0.4)
    c, ga, gb = pair.clearance_with_jacobians(fa, fb)
    c_ref, ga_ref, gb_ref = _autograd_grads(jumbo8, pair, qa, qb, 0.4, -0.4)
    assert torch.equal(c, c_ref)
    ok = c > -0.6  # overlapping axes (distance 0) have no defined direction
    assert ok.sum() > 150
    assert torch.allclose(ga[ok], ga_ref[ok], atol=1e-10, rtol=1e-9)
    assert torch.allclose(gb[ok], gb_ref[ok], atol=1e-10, rtol=1e-9)
    assert (ga.abs().sum(-1) > 0).all() and (gb.abs().sum(-1) > 0).all()


def test_pair_distance_gradients_match_finite_differences(jumbo8):
    """Every capsule pair's distance, both booms' joints, central differences (h = 1e-6)."""
    pair = BoomPair(jumbo8, jumbo8, 0.3)
    qa, qb, fa, fb = _pair_frames(jumbo8, 20, 7, 0.4)
    d, ga, gb = pair.distances_with_jacobians(fa, fb)
    h = 1e-6
    eye = torch.eye(8, dtype=D) * h
    fd = lambda q, y: _shift(jumbo8.frames(q), (0.0, y, 0.0))  # noqa: E731
    num_a = torch.stack([(pair.distances(fd(qa + e, 0.4), fb) - pair.distances(fd(qa - e, 0.4), fb)) / (2 * h)
                         for e in eye], dim=-1)
    num_b = torch.stack([(pair.distances(fa, fd(qb + e, -0.4)) - pair.distances(fa, fd(qb - e, -0.4))) / (2 * h)
                         for e in eye], dim=-1)
    ok = d > -0.3  # skip overlapping axes
    assert ok.sum() > 60
    assert torch.allclose(ga[ok], num_a[ok], atol=1e-6)
    assert torch.allclose(gb[ok], num_b[ok], atol=1e-6)


def test_parallel_booms_side_by_side_by_hand(jumbo8):
    """Home pose, booms at y = +-0.8: booms 1.6 m apart (less 0.4), feeds at y = 0 and -1.6."""
    q = torch.tensor([0, 0, 3.5, 0, 0, 0, 0, 2.5], dtype=D)
    F = jumbo8.frames(q)
    d = BoomPair(jumbo8, jumbo8).distances(_shift(F, (0.0, 0.8, 0.0)), _shift(F, (0.0, -0.8, 0.0)))
    # a's boom (y=0.8) / b's boom (y=-0.8): 1.6 - 0.4; a's feed (y=0) / b's boom: 0.8 - 0.35;
    # a's boom / b's feed (y=-1.6): 2.4 - 0.35; feeds: 1.6 - 0.3.
    assert d.flatten().tolist() == pytest.approx([1.2, 2.05, 0.45, 1.3], abs=1e-12)


def test_bad_d_boom(jumbo8):
    with pytest.raises(ConfigError, match="d_boom"):
        BoomPair(jumbo8, jumbo8, -0.1)
