"""The one particle swarm and the sparrow search, batched over independent problems.

The objective takes a whole population: ``f(x (B, P, D)) -> (B, P)`` for the swarm (``B``
problems, one swarm each: the IK solver's targets), ``(P, D) -> (P,)`` for the single-problem
minimisers :func:`pso_minimize` and :func:`ssa_minimize` (network weights in calibration).

* :class:`Swarm`: inertia-weight PSO (inertia falling linearly from ``w_max`` to ``w_min``,
  velocity clamp, positions clamped into the box), and paper 002's improvements, each a switch of
  :class:`PSOParams`: elite opposition (EOPSO, eq. 14), crossover with the personal best and
  adaptive crossover probabilities (eqs. 15-16, 19-21), adaptive inertia (eqs. 17-18). CEOPSO is
  all three.
* :func:`ssa_minimize`: the sparrow search algorithm (Xue & Shen 2020; paper 004 eqs. 6-10) as its
  authors' reference code runs it: sorted population; producers (the best ``producers`` share)
  forage widely while the alarm value R2 is below the safety threshold ST, and fly off at random
  when it is not; scroungers follow the best producer or, when starving (worse half), fly
  elsewhere; a random ``scouts`` share (the alarm) jumps near the best or, if it is the best,
  away from the worst. Every sparrow remembers its best position, and moves start from it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError
from pipeline.core.settings import rule

DTYPE = torch.float64
Objective = Callable[[torch.Tensor], torch.Tensor]
# Bounds of a config's swarm (calibration.swarm; parse checks them, conf/calibration/default.yaml states them): a
# step evaluates the whole population, each particle a network or a boom pose
MAX_POPULATION = 10_000
MAX_ITERATIONS = 10_000


def _require(checks: Mapping[str, bool], what: str, value) -> None:
    failed = [name for name, ok in checks.items() if not ok]
    if failed:
        raise ConfigError(f"{what}: {', '.join(failed)} required; got {value}")


@dataclass(frozen=True)
class PSOParams:
    """The swarm's settings (``calibration.swarm.pso``; the IK solver's in ``solvers.pso``)."""

    population: int = field(default=30, metadata=rule(ge=2, le=MAX_POPULATION))
    iterations: int = field(default=50, metadata=rule(ge=1, le=MAX_ITERATIONS))
    w_max: float = 0.9
    w_min: float = 0.4
    c1: float = 2.0
    c2: float = 2.0
    v_max: float = 0.2  # share of the box width per step (:func:`pso_minimize`; the IK solver sets its own)
    # random factors: one per coordinate (standard PSO) or one per particle, for all its coordinates (paper 002)
    per_coordinate: bool = True
    stop_at_bounds: bool = False  # a particle clamped onto a bound loses its velocity there (paper 002)
    opposition: bool = False  # EOPSO
    elite_frac: float = 0.1
    crossover: bool = False  # CEOPSO
    p0: float = 0.8  # initial crossover probability (eq. 21)
    pr: float = 0.2  # crossover-probability update probability (eq. 20)
    adaptive_inertia: bool = False  # CEOPSO

    def __post_init__(self):
        _require({
            "population >= 2": self.population >= 2,
            "iterations >= 1": self.iterations >= 1,
            "0 <= w_min <= w_max": 0 <= self.w_min <= self.w_max,
            "c1, c2 >= 0": self.c1 >= 0 and self.c2 >= 0,
            "v_max > 0": self.v_max > 0,
            "0 <= p0 <= 1 and 0 <= pr <= 1": 0 <= self.p0 <= 1 and 0 <= self.pr <= 1,
            "0 < elite_frac <= 1": 0 < self.elite_frac <= 1,
        }, "PSO parameters", self)


@dataclass(frozen=True)
class SSAParams:
    population: int = field(default=30, metadata=rule(ge=3, le=MAX_POPULATION))
    iterations: int = field(default=50, metadata=rule(ge=1, le=MAX_ITERATIONS))
    producers: float = 0.2  # PD: share of producers
    scouts: float = 0.2  # SD: share that perceives danger (the alarm)
    safety: float = 0.8  # ST: safety threshold in [0.5, 1]; the alarm value R2 is uniform in [0, 1]

    def __post_init__(self):
        _require({
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


def keep_better(x: torch.Tensor, f: torch.Tensor, x_new: torch.Tensor, f_new: torch.Tensor):
    """Element-wise the better of two candidate sets ``(..., n)`` by fitness ``(...)``; also which won."""
    take = f_new < f
    return torch.where(take[..., None], x_new, x), torch.where(take, f_new, f), take


def box(lower, upper, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounds ``(dim,)`` from scalars or vectors, checked ``lower < upper``."""
    lo = torch.as_tensor(lower, dtype=DTYPE).expand(dim).clone()
    hi = torch.as_tensor(upper, dtype=DTYPE).expand(dim).clone()
    if not (lo < hi).all():
        raise ValueError(f"swarm bounds: lower < upper required, got {lo.tolist()} / {hi.tolist()}")
    return lo, hi


class Swarm:
    """One swarm per problem, ``(B, P, D)`` tensors: :meth:`step` runs one iteration of eqs. 12-21;
    ``gbest (B, D)`` / ``gbest_f (B,)`` are each problem's best so far."""

    def __init__(self, f: Objective, lower: torch.Tensor, upper: torch.Tensor, vmax: torch.Tensor, batch: int,
                 params: PSOParams, generator: torch.Generator):
        self.f, self.lo, self.hi, self.vmax, self.p, self.g = f, lower, upper, vmax, params, generator
        B, P, D = batch, params.population, lower.shape[-1]
        self.x = lower + torch.rand(B, P, D, generator=generator, dtype=DTYPE) * (upper - lower)
        self.v = (2 * torch.rand(B, P, D, generator=generator, dtype=DTYPE) - 1) * vmax
        fx = f(self.x)
        self.pbest, self.pbest_f = self.x.clone(), fx.clone()
        self.improved = torch.zeros(B, P, dtype=torch.bool)
        self.pc = torch.full((B, P), params.p0, dtype=DTYPE)  # eq. 19: each particle its own crossover probability
        self.update_best()

    def rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.g, dtype=DTYPE)

    def step(self, t: int) -> None:
        """Iteration ``t`` (1-based): move, then the switched-on improvements, then the bests."""
        self.move(self.inertia(t))
        if self.p.opposition:
            self.elite_opposition()
        if self.p.crossover:
            self.crossover(t)
        self.update_best()

    def inertia(self, t: int):
        """Eqs. 17-18 (adaptive: from the share of particles that improved) or linearly decreasing."""
        p = self.p
        if p.adaptive_inertia:
            return ((p.w_max - p.w_min) * self.improved.double().mean(dim=1) + p.w_min)[:, None, None]
        return p.w_max - (p.w_max - p.w_min) * (t - 1) / max(p.iterations - 1, 1)

    def move(self, w) -> None:
        """Eqs. 12-13 with the velocity limit, positions clamped into the box; then each personal
        best keeps the better point."""
        p = self.p
        B, P, D = self.x.shape
        k = D if p.per_coordinate else 1
        v = (w * self.v + p.c1 * self.rand(B, P, k) * (self.pbest - self.x)
             + p.c2 * self.rand(B, P, k) * (self.gbest[:, None] - self.x))
        v = torch.maximum(torch.minimum(v, self.vmax), -self.vmax)
        x = self.x + v
        if p.stop_at_bounds:
            v = torch.where((x < self.lo) | (x > self.hi), torch.zeros_like(v), v)
        self.x, self.v = torch.maximum(torch.minimum(x, self.hi), self.lo), v
        self.pbest, self.pbest_f, self.improved = keep_better(self.pbest, self.pbest_f, self.x, self.f(self.x))

    def elite_opposition(self) -> None:
        """Eq. 14 on the elite personal bests, within the dynamic bounds of the elite group; an
        opposite point outside the box is redrawn inside those bounds."""
        B, P, n = self.x.shape
        n_elite = max(1, math.ceil(self.p.elite_frac * P))
        elite_f, idx = self.pbest_f.topk(n_elite, dim=1, largest=False)
        elite = torch.gather(self.pbest, 1, idx[..., None].expand(-1, -1, n))
        a, b = elite.min(dim=1, keepdim=True).values, elite.max(dim=1, keepdim=True).values
        opp = self.rand(B, n_elite, 1) * (a + b) - elite
        outside = (opp < self.lo) | (opp > self.hi)
        opp = torch.where(outside, a + self.rand(B, n_elite, n) * (b - a), opp)
        new_pb, new_f, take = keep_better(elite, elite_f, opp, self.f(opp))
        self.pbest = self.pbest.scatter(1, idx[..., None].expand(-1, -1, n), new_pb)
        self.pbest_f = self.pbest_f.scatter(1, idx, new_f)
        self.improved = self.improved.scatter(1, idx, torch.gather(self.improved, 1, idx) | take)

    def crossover(self, t: int) -> None:
        """Eqs. 20-21 update each particle's probability, eq. 15 crosses it with its personal best,
        eq. 16 keeps the better."""
        p = self.p
        B, P, n = self.x.shape
        alpha = p.p0 * (1 - t / p.iterations)
        self.pc = torch.where(self.rand(B, P) < p.pr, self.rand(B, P), alpha * self.pc)
        child = torch.where(self.rand(B, P, n) < self.pc[..., None], self.x, self.pbest)
        self.pbest, self.pbest_f, take = keep_better(self.pbest, self.pbest_f, child, self.f(child))
        self.improved = self.improved | take

    def update_best(self) -> None:
        """The best personal best of each swarm (personal bests only improve, so it is the best so far)."""
        i = self.pbest_f.argmin(dim=1)
        rows = torch.arange(len(i))
        self.gbest, self.gbest_f = self.pbest[rows, i], self.pbest_f[rows, i]


def pso_minimize(f: Objective, lower, upper, dim: int, params: PSOParams, seed: int) -> SwarmResult:
    """Minimise ``f ((P, D) -> (P,))`` over a box with one :class:`Swarm`; ``v_max`` is a share of the box width."""
    lo, hi = box(lower, upper, dim)
    swarm = Swarm(lambda x: f(x[0])[None], lo, hi, params.v_max * (hi - lo), 1, params,
                  torch.Generator().manual_seed(int(seed)))
    history = [float(swarm.gbest_f[0])]
    for t in range(1, params.iterations + 1):
        swarm.step(t)
        history.append(float(swarm.gbest_f[0]))
    return SwarmResult(swarm.gbest[0].clone(), history[-1], history)


def _best(X: torch.Tensor, F: torch.Tensor, best: torch.Tensor, best_f: float) -> tuple[torch.Tensor, float]:
    """The swarm's best so far: ``best`` unless a member of ``X`` (fitness ``F``) beats it."""
    i = int(F.argmin())
    return (X[i].clone(), float(F[i])) if float(F[i]) < best_f else (best, best_f)


def ssa_minimize(f: Objective, lower, upper, dim: int, params: SSAParams, seed: int) -> SwarmResult:
    g = torch.Generator().manual_seed(int(seed))
    lo, hi = box(lower, upper, dim)
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
