"""The hybrid solver: analytic Jacobians against autograd, exact and clear from a bad start, and an
honest status for holes that are out of reach or only reachable with a collision."""

import math

import pytest
import torch

from pipeline.assembly.build import load_boom
from pipeline.data.holes import HoleSampling, sample_holes, sample_joints
from pipeline.evaluation.metrics import solution_table
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.solvers.base import HoleTargets, Solver
from pipeline.solvers.hybrid import STATUSES, Candidates, HybridSettings, HybridSolver


# ------------------------------------------------------------------ Jacobians (autograd as the oracle)
@pytest.mark.parametrize("boom_name", ["jumbo8", "huang9", "rescue6"])
def test_analytic_tool_jacobian_equals_autograd(boom_name):
    boom = load_boom(boom_name)
    q = sample_joints(40, boom, seed=1)
    J, _ = boom.point_jacobian(boom.frames(q), boom.tool_pose(q)[0])
    auto = torch.autograd.functional.jacobian(lambda x: boom.tool_pose(x)[0].sum(0), q).permute(1, 0, 2)
    assert torch.allclose(J, auto, atol=1e-10)


def test_analytic_pose6_jacobian_equals_autograd(jumbo8):
    q = sample_joints(200, jumbo8, seed=2)
    J = jumbo8.pose6_jacobian(jumbo8.frames(q))
    auto = torch.autograd.functional.jacobian(lambda x: jumbo8.pose6(x).sum(0), q).permute(1, 0, 2)
    assert torch.allclose(J, auto, atol=1e-10)


def test_point_jacobian_of_a_point_on_an_inner_frame_ignores_later_joints(jumbo8):
    """The boom's end C (frame 3) moves with q1-q3 only."""
    q = sample_joints(30, jumbo8, seed=3)
    J, _ = jumbo8.point_jacobian(jumbo8.frames(q), jumbo8.frames(q)[:, 3, :3, 3], frame=3)
    auto = torch.autograd.functional.jacobian(lambda x: jumbo8.frames(x)[:, 3, :3, 3].sum(0), q).permute(1, 0, 2)
    assert torch.allclose(J, auto, atol=1e-10) and (J[..., 3:] == 0).all()


def test_clearance_values_and_gradients_equal_the_safety_model_and_autograd(safety):
    q = sample_joints(300, safety.boom, seed=4)
    frames = safety.boom.frames(q)
    values, grads = safety.clearances_with_jacobians(frames)
    reference = safety.clearances_from_frames(frames)
    for k in SAFETY_KINDS:
        assert torch.equal(values[k], reference[k]), k
        auto = torch.autograd.functional.jacobian(lambda x, k=k: safety.clearances(x)[k].sum(), q)
        assert torch.allclose(grads[k], auto, atol=1e-9), k


def test_tunnel_surface_gradients_equal_autograd():
    from pipeline.geometry.tunnel import Horseshoe

    tunnel = Horseshoe()
    g = torch.Generator().manual_seed(5)
    y = (torch.rand(2000, generator=g, dtype=torch.float64) * 2 - 1) * 3.0
    z = torch.rand(2000, generator=g, dtype=torch.float64) * 6.5 - 0.3
    y.requires_grad_(True)
    z.requires_grad_(True)
    dist = tunnel.surface_distances(y, z)
    grads = tunnel.surface_gradients(y.detach(), z.detach())
    for k, d in dist.items():
        gy, gz = (torch.zeros_like(y) if g is None else g
                  for g in torch.autograd.grad(d.sum(), (y, z), allow_unused=True, retain_graph=True))
        assert torch.allclose(grads[k][0], gy, atol=1e-12) and torch.allclose(grads[k][1], gz, atol=1e-12), k


# ------------------------------------------------------------------ solving
class Fixed(Solver):
    """A stand-in for the network: answers every hole with the one row of ``q``, or hole ``i`` with
    row ``i`` when ``q`` has a row per hole."""

    def __init__(self, boom, q):
        super().__init__(boom)
        self.q = q

    def _solve(self, targets):
        q = self.q.expand(len(targets), -1) if len(self.q) == 1 else self.q[: len(targets)]
        return q.clone(), torch.ones(len(targets), dtype=torch.long)


def test_from_a_deliberately_bad_start_it_ends_exact_and_clear(safety):
    boom = safety.boom
    pose, _ = sample_holes(40, safety, HoleSampling(), seed=31)
    # boom low and rotated, feed folded back into the boom: self and ground violations at the start
    bad = torch.tensor([[0.7, -0.5, 3.0, 2.5, 1.4, -1.3, 3.0, 1.0]], dtype=torch.float64)
    start_clear = safety.clearances(bad)
    assert min(float(start_clear[k]) for k in SAFETY_KINDS) < 0  # the start itself collides
    solver = HybridSolver(boom, safety, Fixed(boom, bad), HybridSettings(perturbed_starts=0, random_starts=0))
    first = solver.refine(bad.expand(40, -1), pose, use_safety=True)
    full = HybridSolver(boom, safety, Fixed(boom, bad)).solve(HoleTargets(pose, boom.preview_depth))
    assert full.status == ["ok"] * 40
    table = solution_table(pose, full.q, safety)
    assert table["hole_mm"].max() <= 0.01 and not table["any_violation"].any()
    assert boom.within_limits(full.q).all()
    assert (first.hole_error > 1e-5).any()  # one start from there is not enough: the extra starts did it


def test_a_hole_beyond_reach_is_unreachable_and_keeps_its_best_joints(safety):
    P = torch.tensor([[20.0, 0.0, 1.6, 23.3, 0.0, 1.6]], dtype=torch.float64)  # 20 m away, the boom reaches ~9
    res = HybridSolver(safety.boom, safety, None).solve(HoleTargets(P, 3.3))
    assert res.status == ["unreachable"]
    assert res.q.shape == (1, 8) and safety.boom.within_limits(res.q).all()
    assert 10.0 < float(res.errors["hole"][0]) < 20.0  # the closest it got, in metres


def test_a_hole_whose_every_solution_hits_the_wall_is_unsafe(safety):
    """Collar 0.4 m from the wall, drilling straight: the feed beam behind it is 0.25 m inside the
    wall's 0.5 m safety distance whatever the joints, yet the pose itself is reachable."""
    P = torch.tensor([[6.5, 2.1, 1.6, 9.8, 2.1, 1.6]], dtype=torch.float64)
    res = HybridSolver(safety.boom, safety, None).solve(HoleTargets(P, 3.3))
    assert res.status == ["unsafe"]
    assert float(res.errors["hole"][0]) <= 1e-5
    assert float(res.clearances["wall"][0]) == pytest.approx(2.5 - 2.1 - 0.15 - 0.5, abs=1e-6)


def _candidates(hole_mm, worst_clearance):
    """Hand-built candidates: hole errors (mm) and one clearance value (m) for all four kinds."""
    n = len(hole_mm)
    return Candidates(q=torch.zeros(n, 8, dtype=torch.float64),
                      hole_error=torch.tensor(hole_mm, dtype=torch.float64) / 1000,
                      clearances=torch.tensor(worst_clearance, dtype=torch.float64)[:, None].expand(n, 4).clone(),
                      iterations=torch.ones(n, dtype=torch.long), residual=torch.zeros(n, 6, dtype=torch.float64))


def test_a_hole_reached_within_reach_tol_but_colliding_is_unsafe_not_unreachable(safety):
    """docs/solve.md: unreachable means no start reached the pose within reach_tol_mm, whatever the
    collisions; a start at 0.5 mm (tol 0.01, reach 1 mm) that collides reached it: unsafe."""
    solver = HybridSolver(safety.boom, safety, None)
    home = torch.zeros(1, 8, dtype=torch.float64)
    cand = _candidates([0.5, 0.005, 0.5, 5.0, 5.0], [-0.1, -0.1, 0.1, -0.1, 0.1])
    status, _ = solver.rank(cand)
    assert [STATUSES[i] for i in status.tolist()] == ["unsafe", "unsafe", "inexact", "unreachable", "unreachable"]
    # a hole whose candidates are a colliding one within reach and a clear one beyond it is unsafe
    best, best_status = solver.best_of(_candidates([5.0, 0.5], [0.1, -0.1]), 1, home)
    assert STATUSES[int(best_status[0])] == "unsafe" and float(best.hole_error[0]) == pytest.approx(0.5e-3)
    # among unsafe candidates the exact one still wins over an inexact one with a smaller violation
    best, best_status = solver.best_of(_candidates([0.5, 0.005], [-0.01, -0.2]), 1, home)
    assert STATUSES[int(best_status[0])] == "unsafe" and float(best.hole_error[0]) == pytest.approx(0.005e-3)


def test_every_hole_gets_exactly_one_status_and_nothing_is_dropped(safety):
    pose, _ = sample_holes(30, safety, HoleSampling(), seed=32)
    pose = torch.cat([pose, torch.tensor([[30.0, 0, 1.0, 33.3, 0, 1.0]], dtype=torch.float64)])
    res = HybridSolver(safety.boom, safety, None, HybridSettings(random_starts=4)).solve(HoleTargets(pose, 3.3))
    assert len(res.status) == len(pose) == len(res.q) and set(res.status) <= set(STATUSES)
    table = solution_table(pose, res.q, safety)
    for i, status in enumerate(res.status):  # the status says what the joints do
        exact = table["hole_mm"][i] <= 0.01
        clear = not table["any_violation"][i]
        assert (status == "ok") == (exact and clear), (i, status)
        assert status != "unsafe" or table["hole_mm"][i] <= 1.0  # reached within reach_tol_mm
    assert res.status[-1] == "unreachable"


def test_full_turn_joints_wrap_instead_of_stopping(safety):
    solver = HybridSolver(safety.boom, safety, None)
    x = torch.tensor([[0.0, 0.0, 3.5, math.pi + 0.1, 0.0, 0.0, -math.pi - 0.2, 2.0]], dtype=torch.float64)
    out = solver.project(x)
    assert out[0, 3] == pytest.approx(-math.pi + 0.1) and out[0, 6] == pytest.approx(math.pi - 0.2)
    assert out[0, 0] == 0.0 and solver.project(torch.tensor([[2.0, 0, 9, 0, 0, 0, 0, 9]]).double())[0, 2] == 4.6


def test_float32_targets_converge_instead_of_running_out_of_iterations(safety):
    """A float32 pose puts the preview point a rounding error (~1e-7 m) off the boom's preview depth:
    no joints reach it exactly, so refining it as given stalls at that residual for the whole
    budget. The solver refines the nearest reachable pose and reports errors against the pose given."""
    boom = safety.boom
    pose, _ = sample_holes(30, safety, HoleSampling(), seed=33)
    exact = HybridSolver(boom, safety, None).solve(HoleTargets(pose, boom.preview_depth))
    solved = torch.tensor([s == "ok" for s in exact.status])
    assert solved.sum() >= 25
    start = exact.q[solved] + 0.01 * torch.randn(int(solved.sum()), 8, generator=torch.Generator().manual_seed(3),
                                                 dtype=torch.float64)
    settings = HybridSettings()
    res = HybridSolver(boom, safety, Fixed(boom, start), settings).solve(
        HoleTargets(pose[solved].float(), boom.preview_depth))
    assert res.status == ["ok"] * int(solved.sum())
    assert int(res.iterations.max()) < settings.max_iters  # converged, every hole
    table = solution_table(pose[solved].float().double(), res.q, safety)  # errors against the float32 pose
    assert torch.allclose(torch.as_tensor(table["hole_mm"].to_numpy()), res.errors["hole"] * 1000, atol=1e-6)
