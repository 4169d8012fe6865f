"""The compiled kinematics and solver held to the torch ones: the same frames, pose6, Jacobians and
clearances (reference vectors, 1 000 random joints, float64 rounding level), the same network output, and
the same statuses as the torch hybrid. No timing here: speed is shown by the benchmark."""

import math

import numpy as np
import pytest
import torch

from pipeline.assembly.build import load_boom
from pipeline.core.errors import InputError
from pipeline.data.holes import HoleSampling, sample_holes, sample_joints
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.geometry.compiled_kinematics import ChainArrays, SafetyArrays, chain_values, clearance_values
from pipeline.geometry.kinematics import pose_errors
from pipeline.learning.models import build_model
from pipeline.solvers.base import HoleTargets, NetworkSolver, Solver
from pipeline.solvers.compiled import CompiledHybridSolver, CompiledMLP
from pipeline.solvers.hybrid import Candidates, HybridSettings, HybridSolver

r = math.radians
SPEC_Q = [[0, 0, 3.5, 0, 0, 0, 0, 2.5], [r(10), r(15), 4.0, r(30), r(-20), r(10), r(45), 2.0],
          [r(-30), r(40), 3.2, r(-120), r(35), r(-50), r(-90), 3.1]]
SPEC_POSE = [[6.35, -0.8, 1.6, 9.65, -0.8, 1.6], [6.046605, 0.865722, 1.623475, 9.259662, 1.492682, 1.207315],
             [5.034832, -2.479663, 2.146972, 7.639759, -4.226459, 1.120783]]
WORKING_BOX = {"q1": [-17.37, 28.48], "q2": [-9.73, 38.57], "q3": [3.07, 4.59], "q4": [-57.76, 72.99],
               "q5": [-42.08, 20.19], "q6": [-27.49, 34.3], "q7": [-79.82, 86.83], "q8": [1.7, 3.42]}


def test_spec_vectors_through_the_compiled_chain(jumbo8):
    _, pose, _ = chain_values(ChainArrays.from_boom(jumbo8), np.array(SPEC_Q))
    assert np.abs(pose - np.array(SPEC_POSE)).max() < 1e-6  # the reference prints 6 decimals


@pytest.mark.parametrize("boom_name", ["jumbo8", "huang9", "rescue6"])
def test_frames_pose6_and_jacobian_equal_torch_on_random_joints(boom_name):
    boom = load_boom(boom_name)  # modified and standard D-H, an `a` joint (huang9's L1), a locked joint
    q = torch.cat([sample_joints(1000, boom, seed=11), torch.tensor(SPEC_Q, dtype=torch.float64)
                   if boom_name == "jumbo8" else torch.zeros(0, boom.n_joints, dtype=torch.float64)])
    F, pose, J = chain_values(ChainArrays.from_boom(boom), q.numpy())
    frames = boom.frames(q)
    scale = max(1.0, float(frames[..., :3, 3].abs().max()))  # huang9 is in metres of a 6 m boom
    assert np.abs(F - frames.numpy()).max() <= 1e-14 * scale * 10
    if boom.preview_depth is not None:
        assert np.abs(pose - boom.pose6(q).numpy()).max() <= 1e-13 * scale
        assert np.abs(J - boom.pose6_jacobian(frames).numpy()).max() <= 1e-13 * scale
    else:  # the collar rows: the tool point's geometric Jacobian
        linear, _ = boom.point_jacobian(frames, frames[..., boom.tool_index, :3, 3])
        assert np.abs(J[:, :3] - linear.numpy()).max() <= 1e-13 * scale


@pytest.mark.parametrize("exact", [True, False])
def test_clearances_and_their_gradients_equal_the_safety_model(safety, exact):
    safety = safety.__class__(safety.boom, safety.tunnel, safety.distances, 16, exact)
    boom = safety.boom
    bad = torch.tensor([[0.7, -0.5, 3.0, 2.5, 1.4, -1.3, 3.0, 1.0],  # feed folded back into the boom
                        [0.0, 1.1, 4.6, 0.0, -1.1, 0.0, 0.0, 3.5],  # feed up under the arch
                        [0.7, 0.0, 4.6, 0.0, 0.0, -0.7, 0.0, 3.5]], dtype=torch.float64)  # towards the wall
    q = torch.cat([sample_joints(1000, boom, seed=12), bad])
    frames = boom.frames(q)
    C, G = clearance_values(ChainArrays.from_boom(boom), SafetyArrays.from_model(safety), frames.numpy())
    values, grads = safety.clearances_with_jacobians(frames)
    for i, k in enumerate(SAFETY_KINDS):
        assert np.abs(C[:, i] - values[k].numpy()).max() <= 1e-14, k
        assert np.abs(G[:, i] - grads[k].numpy()).max() <= 1e-13, k
    assert (C < 0).any(axis=0).all()  # every kind is violated somewhere: the branches are exercised


def test_compiled_mlp_equals_the_torch_network(jumbo8, safety):
    torch.manual_seed(0)
    pose, _ = sample_holes(200, safety, HoleSampling(), seed=13)
    for activation in ("gelu", "relu", "silu", "tanh"):
        model = build_model(jumbo8, pose.mean(0), pose.std(0), width=64, depth=3, activation=activation).eval()
        with torch.no_grad():
            expected = model(pose.float()).double().numpy()
        span = model.span.double().numpy()
        assert np.abs(CompiledMLP(model)(pose.numpy()) - expected).max() <= 1e-5 * span.max(), activation


class Given(Solver):
    """A stand-in network: the hole ``pose[i]`` starts from ``q[i]`` (found by its pose, so the
    hybrid's cascade may ask for any subset of the holes)."""

    def __init__(self, boom, pose, q):
        super().__init__(boom)
        self.pose, self.q = pose, q

    def _solve(self, targets):
        index = [int(i) for i in torch.cdist(targets.pose, self.pose).argmin(dim=1)]
        return self.q[index].clone(), torch.ones(len(targets), dtype=torch.long)


def _holes_and_starts(safety, n_fk=150, n_face=60):
    """Poses reached by random working-box joints (some only with a collision) with starts a few
    centimetres off, and face holes drawn like the test groups starting from a far posture."""
    boom = safety.boom
    q_true = sample_joints(n_fk, boom, seed=14, box=WORKING_BOX)
    noise = 0.03 * torch.randn(n_fk, boom.n_joints, generator=torch.Generator().manual_seed(15), dtype=torch.float64)
    lo, hi = boom.limits()
    face, _ = sample_holes(n_face, safety, HoleSampling(), seed=16)
    far = torch.tensor([[0.3, 0.5, 3.2, 1.0, -0.5, 0.4, 1.5, 1.5]], dtype=torch.float64).expand(n_face, -1)
    pose = torch.cat([boom.pose6(q_true), face, torch.tensor([[20.0, 0, 1.6, 23.3, 0, 1.6]], dtype=torch.float64)])
    starts = torch.cat([torch.maximum(torch.minimum(q_true + noise, hi), lo), far, far[:1]])
    return pose, starts


def test_statuses_equal_the_torch_hybrid(safety):
    boom = safety.boom
    pose, starts = _holes_and_starts(safety)
    init = Given(boom, pose, starts)
    settings = HybridSettings(deep_starts=16)  # the last resort smaller: the torch side pays for it here
    targets = HoleTargets(pose, boom.preview_depth)
    expected = HybridSolver(boom, safety, init, settings).solve(targets)
    got = CompiledHybridSolver(boom, safety, init, settings).solve(targets)
    assert got.status == expected.status
    assert {"ok", "unreachable"} <= set(got.status) and len(set(got.status)) >= 3  # not all alike
    ok = torch.tensor([s == "ok" for s in got.status])
    same = (got.q - expected.q).abs().max(dim=1).values < 1e-6
    assert same.double().mean() > 0.9  # the same joints, but for a few multi-start holes whose LM paths part
    # the reported errors and clearances are those of the returned joints (the model's, independently)
    err = pose_errors(boom.pose6(got.q), pose)
    assert torch.allclose(got.errors["hole"], err["hole"], atol=1e-12, rtol=0)
    values = safety.clearances(got.q)
    for k in SAFETY_KINDS:
        assert torch.allclose(got.clearances[k], values[k], atol=1e-12, rtol=0), k
    assert (got.errors["hole"][ok] <= 1e-5).all() and all((values[k][ok] >= 0).all() for k in SAFETY_KINDS)


def test_the_fast_path_finishes_the_holes_the_first_stage_makes_ok(safety):
    """Holes whose pose-only answer is not exact and clear by the margin take the cascade's first stage in
    the kernel: some end there ``ok`` (no torch bookkeeping), the rest go on; the torch hybrid, run to
    the same stage, agrees on which."""
    from pipeline.solvers.compiled import fast_path

    boom = safety.boom
    pose, starts = _holes_and_starts(safety)
    settings = HybridSettings(deep_starts=16)
    solver = CompiledHybridSolver(boom, safety, Given(boom, pose, starts), settings)
    tol = settings.tol_mm / 1000
    reference = HybridSolver(boom, safety, None, settings)
    target = reference.consistent(pose)
    first = reference.refine(starts, target, use_safety=False)  # torch: stage 0, every hole
    pose_only = (first.hole_error <= tol) & (first.clearances.min(-1).values >= settings.margin)
    safe = reference.refine(starts, target, use_safety=True)  # stage 1 from the same starts
    both = Candidates.per_hole([first, safe], len(pose))
    _, status = reference.best_of(both, len(pose), starts)
    *_, done = fast_path(pose.numpy(), starts.numpy(), settings.max_iters, tol, *solver._kernel_args())
    done = torch.from_numpy(done)
    assert torch.equal(done, pose_only | (status == 0))
    assert (done & ~pose_only).sum() >= 3 and (~done).sum() >= 3  # both ways out of the first stage occur


def test_one_hole_at_a_time_gives_the_batch_answer(safety):
    """A single hole takes the serial kernel and the compiled MLP; a batch the threads and torch's net."""
    boom = safety.boom
    pose, _ = sample_holes(40, safety, HoleSampling(), seed=17)
    torch.manual_seed(1)
    net = NetworkSolver(boom, build_model(boom, pose.mean(0), pose.std(0), width=32, depth=2, activation="gelu"))
    solver = CompiledHybridSolver(boom, safety, net, HybridSettings(deep_starts=16), parallel_from=8, network_from=8)
    targets = HoleTargets(pose, boom.preview_depth)
    batch = solver.solve(targets)
    single = [solver.solve(targets.subset([i])) for i in range(8)]
    assert [s.status[0] for s in single] == batch.status[:8]
    ok = [i for i in range(8) if batch.status[i] == "ok"]
    assert ok and all(float(single[i].errors["hole"][0]) <= 1e-5 for i in ok)


def test_refine_wants_each_holes_starts_together(safety):
    solver = CompiledHybridSolver(safety.boom, safety, None)
    q0 = torch.tensor(SPEC_Q, dtype=torch.float64)[[0, 1, 1, 0]]
    target = safety.boom.pose6(q0)
    with pytest.raises(InputError, match="starts together"):
        solver.refine(q0, target, use_safety=False, owner=torch.tensor([0, 1, 0, 1]))
    out = solver.refine(q0, target, use_safety=False, owner=torch.tensor([0, 0, 1, 1]))
    assert (out.hole_error[[0, 2]] <= 1e-12).all()  # each hole's first start is its answer already ...
    assert (out.iterations == 0).all()  # ... so both holes stop at once, their second starts too
