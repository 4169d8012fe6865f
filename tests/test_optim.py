"""The optimiser layer against independent answers: LM on linear problems (lstsq), Rosenbrock's
known minimum, per-row stopping, bounds and wrap; the swarm on sphere / Rastrigin; the scaler."""

import math

import pytest
import torch

from pipeline.core.errors import ConfigError
from pipeline.optim.least_squares import Damping, Evaluation, least_squares, projector
from pipeline.optim.scaling import MinMax
from pipeline.optim.swarm import PSOParams, Swarm, pso_minimize, rastrigin, sphere

D = torch.float64


# ------------------------------------------------------------------ least squares
def test_linear_problems_match_lstsq():
    g = torch.Generator().manual_seed(0)
    A = torch.randn(6, 20, 4, generator=g, dtype=D)
    b = torch.randn(6, 20, generator=g, dtype=D)

    def fun(x, rows, current):
        return Evaluation((A[rows] @ x.unsqueeze(-1)).squeeze(-1) - b[rows], A[rows].clone())

    # tiny damping: the first step is Gauss-Newton's, the exact answer of a linear problem; once no step
    # lowers the cost any more, the damping grows past give_up and the row stops before the budget
    out = least_squares(fun, torch.zeros(6, 4, dtype=D), damping=Damping(initial=1e-12, give_up=1.0), max_trials=30)
    expected = torch.linalg.lstsq(A, b.unsqueeze(-1)).solution.squeeze(-1)
    # What the method guarantees, per problem: the damped first step (J^T J + lam D) dx = -J^T r is off
    # Gauss-Newton's by lam ||(A^T A)^-1 D|| ||x*|| (Marquardt's D = diag(A^T A)); later steps cannot
    # remove that (their cost gain is below the cost's rounding); plus the normal equations' rounding,
    # cond(A)^2 eps ||x*|| (x100 for the sums). A fixed 1e-12 sat at the last bits of one BLAS kernel.
    AtA = A.transpose(1, 2) @ A
    Dm = torch.diag_embed(torch.diagonal(AtA, dim1=1, dim2=2))
    size = expected.norm(dim=1)
    bias = 1e-12 * torch.linalg.matrix_norm(torch.linalg.solve(AtA, Dm), ord=2) * size
    rounding = 100 * torch.linalg.cond(A) ** 2 * torch.finfo(D).eps * size
    assert ((out.x - expected).norm(dim=1) <= bias + rounding).all()
    assert (bias + rounding < 1e-11).all()  # still a test of a near-exact answer
    assert (out.steps >= 1).all() and (out.trials < 30).all()


def rosenbrock(x, rows, current):
    """r = [10 (y - x^2), 1 - x]: minimum 0 at (1, 1)."""
    r = torch.stack([10 * (x[:, 1] - x[:, 0] ** 2), 1 - x[:, 0]], -1)
    J = torch.stack([torch.stack([-20 * x[:, 0], torch.full_like(x[:, 0], 10.0)], -1),
                     torch.stack([-torch.ones_like(x[:, 0]), torch.zeros_like(x[:, 0])], -1)], -2)
    return Evaluation(r, J)


@pytest.mark.parametrize("marquardt", [True, False])
def test_rosenbrock_reaches_its_known_minimum_from_several_starts(marquardt):
    x0 = torch.tensor([[-1.2, 1.0], [2.0, -1.0], [-3.0, 5.0], [0.0, 0.0]], dtype=D)
    out = least_squares(rosenbrock, x0, damping=Damping(marquardt=marquardt), max_trials=200, cost_tol=1e-24)
    assert torch.allclose(out.x, torch.ones_like(x0), atol=1e-10, rtol=0)
    assert (out.cost <= 1e-24).all()


def test_finished_rows_leave_the_batch_and_are_not_evaluated_again():
    seen = []

    def fun(x, rows, current):
        seen.append(rows.clone())
        return rosenbrock(x, rows, current)

    x0 = torch.tensor([[1.0, 1.0], [-1.2, 1.0], [0.5, 0.5]], dtype=D)  # row 0 starts at the minimum
    out = least_squares(fun, x0, max_trials=100, cost_tol=1e-20)
    assert out.trials[0] == 0 and (out.trials[1:] > 0).all()
    assert all(0 not in r.tolist() for r in seen[1:])  # only the initial call saw row 0
    for k in (1, 2):  # a row is evaluated once per trial of its own, and not after it stopped
        assert sum(int((r == k).sum()) for r in seen) == 1 + int(out.trials[k])
    assert torch.equal(out.x[0], x0[0])


def test_a_group_stops_once_one_of_its_rows_is_done():
    x0 = torch.tensor([[0.9, 0.8], [-3.0, 5.0], [-3.0, 5.0]], dtype=D)
    groups = torch.tensor([0, 0, 1])
    out = least_squares(rosenbrock, x0, max_trials=200, cost_tol=1e-20, groups=groups)
    assert out.cost[0] <= 1e-20 and out.cost[2] <= 1e-20  # the easy row and the far row alone
    assert out.trials[1] == out.trials[0] < out.trials[2]  # its sibling stopped with it
    assert out.cost[1] > 1e-20


def test_bounds_hold_for_every_trial_point_and_the_answer_sits_on_the_bound():
    """Separable residuals ``w (x - c)`` with ``c`` outside the box: the constrained minimum is ``c``
    clamped into the box, the independent answer."""
    lower, upper = torch.tensor([-2.0, -2.0], dtype=D), torch.tensor([0.5, 2.0], dtype=D)
    c = torch.tensor([[3.0, -0.75], [-5.0, 4.0]], dtype=D)
    w = torch.tensor([1.0, 10.0], dtype=D)
    trials = []

    def fun(x, rows, current):
        trials.append(x.clone())
        return Evaluation(w * (x - c[rows]), torch.diag(w).expand(len(x), 2, 2).clone())

    # tiny damping: the first (Gauss-Newton) step lands on the answer; later ones gain nothing and give up
    out = least_squares(fun, torch.zeros(2, 2, dtype=D), max_trials=100, damping=Damping(initial=1e-12, give_up=1e3),
                        project=projector(lower, upper))
    pts = torch.cat(trials)
    assert ((pts >= lower) & (pts <= upper)).all()
    assert torch.allclose(out.x, torch.maximum(torch.minimum(c, upper), lower), atol=1e-12, rtol=0)


def angle_residual(target):
    def fun(x, rows, current):
        r = torch.cat([torch.sin(x) - math.sin(target), torch.cos(x) - math.cos(target)], -1)
        J = torch.stack([torch.cos(x), -torch.sin(x)], 1)
        return Evaluation(r, J)
    return fun


def test_a_full_turn_joint_wraps_across_pi_where_a_clamp_stops():
    lower, upper = torch.tensor([-math.pi], dtype=D), torch.tensor([math.pi], dtype=D)
    x0 = torch.tensor([[-3.0]], dtype=D)  # the target 3.0 rad is 0.28 rad away across +-pi
    wrapped = least_squares(angle_residual(3.0), x0, max_trials=50, cost_tol=1e-26,
                            project=projector(lower, upper, torch.tensor([True])))
    clamped = least_squares(angle_residual(3.0), x0, max_trials=50, cost_tol=1e-26, project=projector(lower, upper))
    assert float(wrapped.x[0, 0]) == pytest.approx(3.0, abs=1e-12)
    assert float(clamped.x[0, 0]) == pytest.approx(-math.pi, abs=1e-12)
    wrap = projector(lower, upper, torch.tensor([True]))
    assert float(wrap(torch.tensor([[4.0]], dtype=D))) == pytest.approx(4.0 - 2 * math.pi, abs=1e-15)


def test_damping_gives_up_where_no_step_lowers_the_cost():
    """A constant residual: every step is rejected, the damping grows tenfold each time until it
    passes ``give_up``; the Jacobian is computed once (lazily) and never again."""
    calls = {"jac": 0}

    def jac(x, rows):
        calls["jac"] += 1
        return torch.zeros(len(x), 1, 2, dtype=D)

    out = least_squares(lambda x, rows, cur: Evaluation(torch.ones(len(x), 1, dtype=D)), torch.zeros(3, 2, dtype=D),
                        jac=jac, damping=Damping(initial=1e-3, lam_max=math.inf, give_up=1e2), max_trials=100)
    assert out.trials.tolist() == [6, 6, 6]  # 1e-3 -> 1e3 in six rejections
    assert out.steps.tolist() == [0, 0, 0] and calls["jac"] == 1 and out.jacobians.tolist() == [1, 1, 1]


def test_max_steps_counts_accepted_steps_and_record_keeps_the_costs():
    out = least_squares(rosenbrock, torch.tensor([[-1.2, 1.0]], dtype=D), max_steps=3, record=True)
    assert int(out.steps[0]) == 3 == sum(int(a[0]) for a in out.accepted)
    accepted = [float(c[0]) for c, a in zip(out.costs, out.accepted, strict=True) if a[0]]
    assert accepted == sorted(accepted, reverse=True) and accepted[-1] == float(out.cost[0])


def test_a_budget_is_required_and_bad_damping_is_named():
    with pytest.raises(ConfigError, match="max_trials or max_steps"):
        least_squares(rosenbrock, torch.zeros(1, 2, dtype=D))
    with pytest.raises(ConfigError, match="damping"):
        Damping(down=2.0)


# ------------------------------------------------------------------ swarm
def test_a_batched_swarm_finds_each_problems_own_minimum():
    centres = torch.tensor([[1.0, -2.0, 0.5], [-3.0, 0.0, 2.0]], dtype=D)
    lo, hi = torch.full((3,), -5.0, dtype=D), torch.full((3,), 5.0, dtype=D)
    p = PSOParams(population=40, iterations=150)
    swarm = Swarm(lambda x: sphere(x - centres[:, None]), lo, hi, 0.2 * (hi - lo), 2, p,
                  torch.Generator().manual_seed(0))
    best = [swarm.gbest_f.clone()]
    for t in range(1, p.iterations + 1):
        swarm.step(t)
        best.append(swarm.gbest_f.clone())
    assert torch.allclose(swarm.gbest, centres, atol=1e-3)
    assert all((b <= a).all() for a, b in zip(best, best[1:], strict=False))  # the best only improves


@pytest.mark.parametrize("variant", [{}, {"opposition": True},
                                     {"opposition": True, "crossover": True, "adaptive_inertia": True}])
def test_paper_002_variants_solve_rastrigin_in_two_dimensions(variant):
    p = PSOParams(population=60, iterations=200, w_min=0.4, w_max=0.9, per_coordinate=False, stop_at_bounds=True,
                  **variant)
    res = pso_minimize(lambda x: rastrigin(x - 0.7), -5.12, 5.12, 2, p, seed=1)
    assert res.f < 1e-6 and torch.allclose(res.x, torch.full((2,), 0.7, dtype=D), atol=1e-4)
    assert res.history == sorted(res.history, reverse=True)


def test_swarm_positions_stay_in_the_box():
    lo, hi = torch.tensor([0.0, -1.0], dtype=D), torch.tensor([1.0, 0.0], dtype=D)
    seen = []

    def f(x):
        seen.append(x.clone())
        return sphere(x - 3.0)  # the minimum lies outside the box: the swarm presses on its corner

    swarm = Swarm(f, lo, hi, 0.5 * (hi - lo), 1, PSOParams(population=10, iterations=20, stop_at_bounds=True),
                  torch.Generator().manual_seed(2))
    for t in range(1, 21):
        swarm.step(t)
    pts = torch.cat([s.reshape(-1, 2) for s in seen])
    assert ((pts >= lo) & (pts <= hi)).all()
    assert torch.allclose(swarm.gbest[0], torch.tensor([1.0, 0.0], dtype=D))


def test_bad_swarm_parameters_are_named():
    with pytest.raises(ConfigError, match="population"):
        PSOParams(population=1)


# ------------------------------------------------------------------ scaler
def test_minmax_maps_onto_minus_one_one_and_back():
    g = torch.Generator().manual_seed(3)
    x = torch.randn(50, 4, generator=g, dtype=D) * torch.tensor([1.0, 10.0, 1e-3, 5.0], dtype=D)
    s = MinMax.fit(x)
    y = s(x)
    lo, hi = x.min(0).values, x.max(0).values
    assert torch.allclose(y, 2 * (x - lo) / (hi - lo) - 1, atol=1e-15, rtol=0)  # mapminmax's formula
    assert torch.equal(y.min(0).values, torch.full((4,), -1.0, dtype=D))
    assert torch.allclose(y.max(0).values, torch.ones(4, dtype=D), atol=1e-15, rtol=0)
    assert torch.allclose(s.inverse(y), x, atol=1e-12, rtol=0)


def test_a_constant_column_maps_to_zero_and_back_without_dividing_by_zero():
    x = torch.tensor([[1.0, 2.25], [3.0, 2.25], [2.0, 2.25]], dtype=D)
    s = MinMax.fit(x)
    y = s(x)
    assert torch.equal(y[:, 1], torch.zeros(3, dtype=D)) and torch.isfinite(y).all()
    assert torch.equal(s(torch.tensor([[2.0, 7.0]], dtype=D))[0, 1], torch.tensor(0.0, dtype=D))
    assert torch.equal(s.inverse(y)[:, 1], x[:, 1]) and torch.allclose(s.inverse(y), x, atol=1e-15, rtol=0)
