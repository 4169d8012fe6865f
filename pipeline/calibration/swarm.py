"""Population optimisers over a box, batched: the objective takes a whole population ``(P, D)``
and returns ``(P,)``, so one call evaluates every particle (here: every candidate BP network).

* :func:`pso_minimize`: standard inertia-weight PSO (inertia falling linearly from ``w_max`` to
  ``w_min``, velocity clamp). The project's PSO (:mod:`pipeline.solvers.pso`) is an IK solver bound
  to joint spaces and pose targets, so a generic one is used for network weights.
* :func:`ssa_minimize`: the sparrow search algorithm (Xue & Shen 2020; paper 004 eqs. 6-10) as its
  authors' reference code runs it: sorted population; producers (the best ``producers`` share)
  forage widely while the alarm value R2 is below the safety threshold ST, and fly off at random
  when it is not; scroungers follow the best producer or, when starving (worse half), fly
  elsewhere; a random ``scouts`` share (the alarm) jumps near the best or, if it is the best,
  away from the worst. Every sparrow remembers its best position, and moves start from it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from pipeline.solvers.base import require
from pipeline.solvers.pso import keep_better

DTYPE = torch.float64
Objective = Callable[[torch.Tensor], torch.Tensor]


@dataclass(frozen=True)
class PSOParams:
    population: int = 30
    iterations: int = 50
    w_max: float = 0.9
    w_min: float = 0.4
    c1: float = 2.0
    c2: float = 2.0
    v_max: float = 0.2  # share of the box width per step

    def __post_init__(self):
        require({
            "population >= 2": self.population >= 2,
            "iterations >= 1": self.iterations >= 1,
            "0 <= w_min <= w_max": 0 <= self.w_min <= self.w_max,
            "c1, c2 >= 0": self.c1 >= 0 and self.c2 >= 0,
            "v_max > 0": self.v_max > 0,
        }, "calibration.swarm.pso", self)


@dataclass(frozen=True)
class SSAParams:
    population: int = 30
    iterations: int = 50
    producers: float = 0.2  # PD: share of producers
    scouts: float = 0.2  # SD: share that perceives danger (the alarm)
    safety: float = 0.8  # ST: safety threshold in [0.5, 1]; the alarm value R2 is uniform in [0, 1]

    def __post_init__(self):
        require({
            "population >= 3": self.population >= 3,
            "iterations >= 1": self.iterations >= 1,
            "0 < producers < 1": 0 < self.producers < 1,
            "0 <= scouts <= 1": 0 <= self.scouts <= 1,
            "0.5 <= safety <= 1": 0.5 <= self.safety <= 1,
        }, "calibration.swarm.ssa", self)


@dataclass
class SwarmResult:
    x: torch.Tensor  # best position (D,)
    f: float  # its objective
    history: list[float]  # best objective after each iteration (index 0: initial population)


def _box(lower, upper, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    lo = torch.as_tensor(lower, dtype=DTYPE).expand(dim).clone()
    hi = torch.as_tensor(upper, dtype=DTYPE).expand(dim).clone()
    if not (lo < hi).all():
        raise ValueError(f"swarm bounds: lower < upper required, got {lo.tolist()} / {hi.tolist()}")
    return lo, hi


def pso_minimize(f: Objective, lower, upper, dim: int, params: PSOParams, seed: int) -> SwarmResult:
    g = torch.Generator().manual_seed(int(seed))
    lo, hi = _box(lower, upper, dim)
    P = params.population
    vmax = params.v_max * (hi - lo)
    x = lo + torch.rand(P, dim, generator=g, dtype=DTYPE) * (hi - lo)
    v = (2 * torch.rand(P, dim, generator=g, dtype=DTYPE) - 1) * vmax
    fx = f(x)
    pbest, pbest_f = x.clone(), fx.clone()
    i = int(pbest_f.argmin())
    gbest, gbest_f = pbest[i].clone(), float(pbest_f[i])
    history = [gbest_f]
    for t in range(params.iterations):
        w = params.w_max - (params.w_max - params.w_min) * t / max(params.iterations - 1, 1)
        r1, r2 = torch.rand(P, dim, generator=g, dtype=DTYPE), torch.rand(P, dim, generator=g, dtype=DTYPE)
        v = w * v + params.c1 * r1 * (pbest - x) + params.c2 * r2 * (gbest - x)
        v = torch.maximum(torch.minimum(v, vmax), -vmax)
        x = torch.maximum(torch.minimum(x + v, hi), lo)
        pbest, pbest_f, _ = keep_better(pbest, pbest_f, x, f(x))
        gbest, gbest_f = _best(pbest, pbest_f, gbest, gbest_f)
        history.append(gbest_f)
    return SwarmResult(gbest, gbest_f, history)


def _best(X: torch.Tensor, F: torch.Tensor, best: torch.Tensor, best_f: float) -> tuple[torch.Tensor, float]:
    """The swarm's best so far: ``best`` unless a member of ``X`` (fitness ``F``) beats it."""
    i = int(F.argmin())
    return (X[i].clone(), float(F[i])) if float(F[i]) < best_f else (best, best_f)


def ssa_minimize(f: Objective, lower, upper, dim: int, params: SSAParams, seed: int) -> SwarmResult:
    g = torch.Generator().manual_seed(int(seed))
    lo, hi = _box(lower, upper, dim)
    n, T = params.population, params.iterations
    n_prod = max(1, round(params.producers * n))
    n_scout = round(params.scouts * n)
    clamp = lambda x: torch.maximum(torch.minimum(x, hi), lo)  # noqa: E731
    randn = lambda *s: torch.randn(*s, generator=g, dtype=DTYPE)  # noqa: E731
    rand = lambda *s: torch.rand(*s, generator=g, dtype=DTYPE)  # noqa: E731

    X = lo + rand(n, dim) * (hi - lo)  # each sparrow's best position so far (the reference code's pX)
    F = f(X)
    i = int(F.argmin())
    best, best_f = X[i].clone(), float(F[i])
    history = [best_f]
    rank = torch.arange(1, n + 1, dtype=DTYPE)  # 1-based rank after sorting, as in eqs. 8-9
    for _ in range(T):
        order = F.argsort()
        X, F = X[order], F[order]
        worst = X[-1]
        new = torch.empty_like(X)
        # eq. 8, producers: R2 < ST, no predator: wide search X exp(-i / (alpha T)); else fly off by Q L
        r2 = float(rand(1))
        if r2 < params.safety:
            alpha = 1.0 - rand(n_prod, 1)  # (0, 1]
            new[:n_prod] = X[:n_prod] * torch.exp(-rank[:n_prod, None] / (alpha * T))
        else:
            new[:n_prod] = X[:n_prod] + randn(n_prod, 1)
        new[:n_prod] = clamp(new[:n_prod])
        f_prod = f(new[:n_prod])
        xp = new[int(f_prod.argmin())]  # the best producer's position, which scroungers follow
        # eq. 9, scroungers: the worse half starves and flies elsewhere, Q exp((X_worst - X_i) / i^2);
        # the rest forage around the best producer, X_P + |X_i - X_P| A+ L (A: random +-1 row, A+ = A^T / D)
        m = n - n_prod
        if m:
            r = rank[n_prod:, None]
            starving = r > n / 2
            A = torch.randint(0, 2, (m, dim), generator=g).to(DTYPE) * 2 - 1
            step = ((X[n_prod:] - xp).abs() * A).sum(-1, keepdim=True) / dim
            far = randn(m, 1) * torch.exp((worst - X[n_prod:]) / r**2)
            new[n_prod:] = clamp(torch.where(starving, far, xp + step))
        # eq. 10, the alarm: a random share of scouts; one worse than the global best jumps next to
        # it, X_best + beta |X_i - X_best|; the global best itself moves away from the worst,
        # X_i + K |X_i - X_worst| / (f_i - f_worst + eps)
        if n_scout:
            idx = torch.randperm(n, generator=g)[:n_scout]
            xs, fs = X[idx], F[idx]
            towards = best + randn(n_scout, dim) * (xs - best).abs()
            k = 2 * rand(n_scout, 1) - 1
            away = xs + k * (xs - worst).abs() / ((fs - F[-1]).unsqueeze(-1) + 1e-50)
            away = torch.nan_to_num(away, nan=0.0)  # 0 * inf when a scout sits on the worst
            new[idx] = clamp(torch.where((fs > best_f).unsqueeze(-1), towards, away))
            prod_scouts = idx[idx < n_prod]
        else:
            prod_scouts = torch.empty(0, dtype=torch.long)
        f_new = torch.empty_like(F)
        rest = torch.ones(n, dtype=torch.bool)
        rest[:n_prod] = False
        rest[prod_scouts] = True  # a producer turned scout has a new position to evaluate
        f_new[:n_prod] = f_prod
        if rest.any():
            f_new[rest] = f(new[rest])
        X, F, _ = keep_better(X, F, new, f_new)  # each sparrow keeps its best position (the reference code's memory)
        best, best_f = _best(X, F, best, best_f)
        history.append(best_f)
    return SwarmResult(best, best_f, history)


def sphere(x: torch.Tensor) -> torch.Tensor:
    """Test function: minimum 0 at the origin."""
    return (x * x).sum(-1)


def rastrigin(x: torch.Tensor) -> torch.Tensor:
    """Test function (many local minima on the integer grid): minimum 0 at the origin."""
    return 10 * x.shape[-1] + (x * x - 10 * torch.cos(2 * math.pi * x)).sum(-1)
