"""The compiled rig clearances held to the torch ones: each mounted boom's four clearances (the safety
model on rig-frame frames) and the boom-boom clearance (BoomPair), on random joints of every boom of
`twin` and `trio`, both signs, broadcast batches, either order of the booms, NaN joints; a calibrated
boom's chain; and a boom that only looks calibrated, kept on torch. No timing here."""

import math

import pytest
import torch

from pipeline.assembly.rig import load_rig, rig_booms, rig_spec
from pipeline.calibration.error_model import BoomWithErrors, ErrorLevel, draw_errors
from pipeline.core.config import load_group_file
from pipeline.core.errors import InputError
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.geometry.compiled_kinematics import ChainArrays
from pipeline.geometry.compiled_rig import pair_clearance
from pipeline.geometry.tunnel import Horseshoe

D = torch.float64


def _torch_clearance(rig, a, qa, b, qb):
    """BoomPair's clearance of the rig-frame frames: the path the kernel replaces."""
    if a > b:
        a, qa, b, qb = b, qb, a, qa
    return rig.pair(a, b).clearance(rig.booms[a].frames(qa), rig.booms[b].frames(qb))


def _joints(boom, n, seed):
    g = torch.Generator().manual_seed(seed)
    lo, hi = boom.limits(D)
    return boom.with_locks(lo + (hi - lo) * torch.rand(n, boom.n_joints, generator=g, dtype=D))


@pytest.fixture(scope="module")
def rigs(safety):
    wide = Horseshoe.from_config(load_group_file("tunnel", "horseshoe_wide"))
    return {"twin": load_rig("twin", safety.tunnel, safety.distances, safety.points_per_capsule),
            "trio": load_rig("trio", wide, safety.distances, safety.points_per_capsule)}


@pytest.mark.parametrize("name", ["twin", "trio"])
def test_equals_the_torch_pair_on_random_joints(rigs, name):
    rig = rigs[name]
    for a in range(len(rig)):
        for b in range(a + 1, len(rig)):
            qa, qb = _joints(rig.booms[a].boom, 2000, 10 * a + b), _joints(rig.booms[b].boom, 2000, 100 + a + b)
            fast, slow = rig.boom_clearance(a, qa, b, qb), _torch_clearance(rig, a, qa, b, qb)
            assert fast.shape == slow.shape == (2000,) and fast.dtype == D
            assert (slow < 0).any() and (slow > 0).any()  # overlapping and clear pairs both in the sample
            assert (fast - slow).abs().max() <= 1e-12
            assert torch.equal(fast < 0, slow < 0)
            # the other order of the booms gives the same numbers
            assert torch.equal(rig.boom_clearance(b, qb, a, qa), fast)


def _every_pair_minimum(Ea, Eb, ia, ib, ra, rb, d_boom):
    """The boom-boom clearance with every capsule pair measured (no bound, no skipping), by the same
    segment distance: what the pruned kernel must return to the last bit."""
    from pipeline.geometry.compiled_kinematics import segment_distance

    out = []
    for p in range(len(ia)):
        ea, eb = Ea[ia[p]], Eb[ib[p]]
        cs = [segment_distance(ea[2 * i], ea[2 * i + 1], eb[2 * j], eb[2 * j + 1])[0] - ra[i] - rb[j]
              for i in range(len(ra)) for j in range(len(rb))]
        finite = [c for c in cs if c == c]
        out.append((min(finite) if finite else math.inf) - d_boom)
    return out


def test_the_pruned_pair_kernel_returns_every_pairs_minimum_to_the_last_bit(rigs):
    """indexed_clearances skips capsule pairs by a midpoint bound; on random configurations of twin (far,
    touching and interpenetrating), on configurations sharing capsule ends exactly (zero-length gaps) and
    on NaN ends, it returns exactly the minimum over every pair."""
    import numpy as np

    from pipeline.geometry.compiled_rig import indexed_clearances

    rig = rigs["twin"]
    ka, kb = rig.booms[0].kernel, rig.booms[1].kernel
    qa, qb = _joints(rig.booms[0].boom, 600, 7), _joints(rig.booms[1].boom, 600, 8)
    Ea, Eb = ka.ends(qa.numpy()), kb.ends(qb.numpy())
    Eb[:50] = Ea[:50]  # the same capsule ends on both sides (coincident segments)
    Ea[-3:] = np.nan
    ia = np.arange(600)
    ib = np.concatenate([np.arange(50), 50 + np.random.default_rng(0).permutation(550)])  # 0-49: coincident
    fast = indexed_clearances(Ea, Eb, ia, ib, ka.radius, kb.radius, 0.3)
    slow = np.array(_every_pair_minimum(Ea, Eb, ia, ib, ka.radius, kb.radius, 0.3))
    assert (fast < 0).any() and (fast > 0.5).any()
    assert np.array_equal(fast, slow)


@pytest.mark.parametrize("name", ["twin", "trio"])
def test_each_boom_s_clearances_equal_the_safety_model_from_its_base(rigs, name):
    rig = rigs[name]
    for i, m in enumerate(rig.booms):
        q = _joints(m.boom, 2000, 7 + i)
        fast, slow = m.clearances(q), m.safety.clearances_from_frames(m.frames(q))
        for k in SAFETY_KINDS:
            assert fast[k].shape == (2000,)
            assert (fast[k] - slow[k]).abs().max() <= 1e-12, (m.name, k)
            assert torch.equal(fast[k] < 0, slow[k] < 0)
        assert any(bool((slow[k] < 0).any()) for k in SAFETY_KINDS)  # violations in the sample too


def test_joints_that_are_not_finite_are_never_clear(rigs):
    rig = rigs["twin"]
    qa, qb = _joints(rig.booms[0].boom, 4, 8), _joints(rig.booms[1].boom, 4, 9)
    qa[1, 3], qb[2, 0] = float("nan"), float("inf")
    c, slow = rig.boom_clearance(0, qa, 1, qb), _torch_clearance(rig, 0, qa, 1, qb)
    assert c[1] == c[2] == -math.inf and torch.equal(c[[0, 3]], slow[[0, 3]])
    own, torch_own = rig.booms[0].clearances(qa), rig.booms[0].safety.clearances_from_frames(rig.booms[0].frames(qa))
    for k in SAFETY_KINDS:
        assert own[k][1] == -math.inf and not bool(torch_own[k][1] >= 0)  # torch: NaN or negative, by kind
        assert torch.equal(own[k][[0, 2, 3]], torch_own[k][[0, 2, 3]])


def test_broadcast_batches_as_the_oracle_asks(rigs):
    rig = rigs["twin"]
    qa, qb = _joints(rig.booms[0].boom, 30, 1), _joints(rig.booms[1].boom, 40, 2)
    grid = rig.boom_clearance(0, qa[:, None, :], 1, qb[None, :, :])  # every standing pairing at once
    assert grid.shape == (30, 40)
    assert (grid - _torch_clearance(rig, 0, qa[:, None, :], 1, qb[None, :, :])).abs().max() <= 1e-12
    one = rig.boom_clearance(0, qa, 1, qb[:1])  # one boom standing against many instants of the other
    assert one.shape == (30,) and torch.equal(one, grid[:, 0])


def test_gradients_and_float32_take_torch(rigs):
    rig = rigs["twin"]
    qa, qb = _joints(rig.booms[0].boom, 5, 3), _joints(rig.booms[1].boom, 5, 4)
    c = rig.boom_clearance(0, qa.clone().requires_grad_(True), 1, qb)
    assert c.grad_fn is not None  # differentiable: the torch path
    assert rig.boom_clearance(0, qa.float(), 1, qb.float()).dtype == torch.float32


def _calibrated_twin(safety, boom_class=BoomWithErrors):
    booms = dict(rig_booms(rig_spec("twin")))
    nominal = booms["L"]
    booms["L"] = boom_class(nominal, draw_errors(nominal, ErrorLevel(0.5, 0.5, 20.0), seed=0))
    return load_rig("twin", safety.tunnel, safety.distances, safety.points_per_capsule, booms=booms), nominal


def test_a_calibrated_boom_s_kernel_computes_its_calibrated_chain(safety, rigs):
    """The kernels know the calibrated chain (each link premultiplied by its error transform): a calibrated
    boom's own clearances and its boom-boom clearance equal torch's on the calibrated frames, which the
    nominal chain's are not."""
    rig, nominal = _calibrated_twin(safety)
    qa, qb = _joints(nominal, 2000, 5), _joints(rig.booms[1].boom, 2000, 6)
    assert rig.booms[0].kernel is not None and rig.booms[0].kernel.chain[-1].shape == (nominal.n_rows, 4, 4)
    c = rig.boom_clearance(0, qa, 1, qb)
    slow = _torch_clearance(rig, 0, qa, 1, qb)  # the calibrated chain, through torch
    assert (c - slow).abs().max() <= 1e-12 and torch.equal(c < 0, slow < 0)
    assert (slow < 0).any() and (slow > 0).any()
    own = rig.booms[0].clearances(qa)
    torch_own = rig.booms[0].safety.clearances_from_frames(rig.booms[0].frames(qa))
    assert all((own[k] - torch_own[k]).abs().max() <= 1e-12 for k in SAFETY_KINDS)
    assert (c - rigs["twin"].boom_clearance(0, qa, 1, qb)).abs().max() > 1e-3  # not the nominal chain's
    with pytest.raises(InputError, match="boom 'jumbo8' \\(BoomWithErrors\\).*compiled kernels know only"):
        ChainArrays.from_boom(rig.booms[0].boom)  # the hybrid's kernels (they need the Jacobian too)


class _NotItsErrors(BoomWithErrors):
    """BoomWithErrors' interface, but links that are not ``E_i @ T_i``: a kernel built from the interface
    would compute another chain."""

    def link_transforms(self, q):
        links = super().link_transforms(q).clone()
        links[..., 2, :3, 3] += 0.01
        return links


def test_a_boom_that_only_looks_calibrated_stays_on_torch(safety):
    rig, nominal = _calibrated_twin(safety, _NotItsErrors)
    assert rig.booms[0].kernel is None and rig.booms[1].kernel is not None  # the probe of its frames refused it
    qa, qb = _joints(nominal, 200, 7), _joints(rig.booms[1].boom, 200, 8)
    assert torch.equal(rig.boom_clearance(0, qa, 1, qb), _torch_clearance(rig, 0, qa, 1, qb))


def test_bad_joint_shapes_are_named(rigs):
    rig = rigs["twin"]
    ka, kb = rig.booms[0].kernel, rig.booms[1].kernel
    with pytest.raises(InputError, match="boom b's joints have shape \\(4, 7\\), expected \\(..., 8\\)"):
        pair_clearance(ka, torch.zeros(4, 8, dtype=D), kb, torch.zeros(4, 7, dtype=D), 0.3)
    with pytest.raises(InputError, match="boom 'jumbo8''s joints have shape \\(3,\\)"):
        ka.clearances(torch.zeros(3, dtype=D))
