"""PSO, EOPSO and CEOPSO (paper 002, eqs. 11-21), vectorised over targets and particles.

One swarm per target; every tensor is ``(targets, particles, joints)``. The three methods are
one algorithm with three switches, so each improvement can be turned off on its own:

* ``opposition`` (EOPSO): elite opposition-based learning, eq. 14, on the best ``elite_frac`` of
  the personal bests with dynamic bounds of the elite group;
* ``crossover`` (CEOPSO): discrete crossover of each particle with its personal best, eqs. 15-16,
  with a per-particle adaptive crossover probability, eqs. 19-21;
* ``adaptive_inertia`` (CEOPSO): inertia from the share of particles that improved, eqs. 17-18;
  otherwise the inertia falls linearly from ``w_max`` to ``w_min`` (standard PSO).

Fitness (eq. 11) is ``w_pos * position error (m) + w_ori * orientation error (rad)``; paper 002
weights both 0.5 but does not state its units, so SI units are used here (decided in
``docs/benchmarks.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import JointSpace, Solver, Targets, require, tool_transform


@dataclass(frozen=True)
class PSOParams:
    population: int = 800
    iterations: int = 100
    w_min: float = 0.6
    w_max: float = 0.8
    v_max_revolute: float = 0.1  # rad per step
    v_max_prismatic: float = 0.1  # m per step
    c1: float = 2.0
    c2: float = 2.0
    p0: float = 0.8  # initial crossover probability (eq. 21)
    pr: float = 0.2  # crossover-probability update probability (eq. 20)
    elite_frac: float = 0.1
    opposition: bool = False
    crossover: bool = False
    adaptive_inertia: bool = False
    w_pos: float = 0.5
    w_ori: float = 0.5
    tol_pos: float = 0.0  # stop a target early once its best meets both tolerances (0: never)
    tol_ori: float = 0.0
    seed: int = 0

    def __post_init__(self):
        require({
            "population >= 2": self.population >= 2,
            "iterations >= 1": self.iterations >= 1,
            "0 <= w_min <= w_max": 0 <= self.w_min <= self.w_max,
            "v_max > 0": self.v_max_revolute > 0 and self.v_max_prismatic > 0,
            "0 <= p0 <= 1 and 0 <= pr <= 1": 0 <= self.p0 <= 1 and 0 <= self.pr <= 1,
            "0 < elite_frac <= 1": 0 < self.elite_frac <= 1,
        }, "PSO parameters", self)


PRESETS = {
    "pso": {},
    "eopso": {"opposition": True},
    "ceopso": {"opposition": True, "crossover": True, "adaptive_inertia": True},
}


def params_for(variant: str, overrides: Mapping | None = None) -> PSOParams:
    if variant not in PRESETS:
        raise ConfigError(f"PSO variant {variant!r}: expected one of {sorted(PRESETS)}")
    return PSOParams(**{**PRESETS[variant], **dict(overrides or {})})


@dataclass
class SwarmTrace:
    """Per-iteration position / orientation error of each target's global best ``(iters+1, B)``."""

    position: torch.Tensor
    orientation: torch.Tensor

    def first_reach(self, tol_pos: float, tol_ori: float) -> torch.Tensor:
        """First iteration at which each target met both tolerances; -1 where it never did."""
        ok = (self.position <= tol_pos) & (self.orientation <= tol_ori)
        first = ok.long().argmax(dim=0)
        return torch.where(ok.any(dim=0), first, torch.full_like(first, -1))


class ParticleSwarm(Solver):
    def __init__(self, boom: Boom, params: PSOParams, locks: Mapping[str, float] | None = None, name: str = "pso"):
        super().__init__(boom)
        self.p = params
        self.space = JointSpace(boom, locks)
        self.name = name
        self.trace: SwarmTrace | None = None

    def fitness(self, x: torch.Tensor, targets: Targets) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        err = targets.errors(tool_transform(self.boom, self.space.full(x)))
        return self.p.w_pos * err["position"] + self.p.w_ori * err["orientation"], err

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        p = self.p
        swarm = _Swarm.start(self, targets, torch.Generator().manual_seed(p.seed))
        trace = [swarm.best_errors()]
        iters = torch.full((len(targets),), p.iterations, dtype=torch.long)
        done = torch.zeros(len(targets), dtype=torch.bool)
        for t in range(1, p.iterations + 1):
            swarm.move(self.inertia(swarm, t))
            if p.opposition:
                swarm.elite_opposition()
            if p.crossover:
                swarm.crossover(t)
            swarm.update_best()
            trace.append(swarm.best_errors())
            if p.tol_pos > 0 and p.tol_ori > 0:
                reached = ~done & (trace[-1][0] <= p.tol_pos) & (trace[-1][1] <= p.tol_ori)
                iters = torch.where(reached, torch.full_like(iters, t), iters)
                done = done | reached
                if done.all():
                    break
        self.trace = SwarmTrace(torch.stack([e[0] for e in trace]), torch.stack([e[1] for e in trace]))
        return self.space.full(swarm.gbest), iters

    def inertia(self, swarm: _Swarm, t: int):
        """Eqs. 17-18 (adaptive: from the share of particles that improved) or linearly decreasing."""
        p = self.p
        if p.adaptive_inertia:
            return ((p.w_max - p.w_min) * swarm.improved.double().mean(dim=1) + p.w_min)[:, None, None]
        return p.w_max - (p.w_max - p.w_min) * (t - 1) / max(p.iterations - 1, 1)


def keep_better(x: torch.Tensor, f: torch.Tensor, x_new: torch.Tensor, f_new: torch.Tensor):
    """Element-wise the better of two candidate sets ``(..., n)`` by fitness ``(...)``; also which won."""
    take = f_new < f
    return torch.where(take[..., None], x_new, x), torch.where(take, f_new, f), take


@dataclass
class _Swarm:
    """State of one swarm per target: ``(targets, particles, joints)`` tensors and the steps of
    eqs. 12-21 on them."""

    solver: ParticleSwarm
    targets: Targets
    g: torch.Generator
    x: torch.Tensor
    v: torch.Tensor
    pbest: torch.Tensor
    pbest_f: torch.Tensor
    improved: torch.Tensor
    pc: torch.Tensor  # eq. 19: each particle carries its own crossover probability
    vmax: torch.Tensor
    gbest: torch.Tensor

    @classmethod
    def start(cls, solver: ParticleSwarm, targets: Targets, g: torch.Generator) -> _Swarm:
        p, space = solver.p, solver.space
        B, P, n = len(targets), p.population, space.n
        vmax = torch.where(space.revolute, p.v_max_revolute, p.v_max_prismatic).double()
        vmax = torch.minimum(vmax, (space.upper - space.lower).clamp_min(1e-12))
        x = space.uniform((B, P), g)
        v = (2 * torch.rand(B, P, n, generator=g, dtype=torch.float64) - 1) * vmax
        f, _ = solver.fitness(x, targets)
        swarm = cls(solver, targets, g, x, v, x.clone(), f.clone(), torch.zeros(B, P, dtype=torch.bool),
                    torch.full((B, P), p.p0, dtype=torch.float64), vmax, x[:, 0])
        swarm.update_best()
        return swarm

    def rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.g, dtype=torch.float64)

    def move(self, w) -> None:
        """Eqs. 12-13 with the velocity limit; a particle leaving the ranges is put back on the bound
        with its velocity there zeroed. Then each personal best keeps the better point."""
        p, space = self.solver.p, self.solver.space
        B, P, _ = self.x.shape
        v = (w * self.v + p.c1 * self.rand(B, P, 1) * (self.pbest - self.x)
             + p.c2 * self.rand(B, P, 1) * (self.gbest[:, None] - self.x))
        v = torch.maximum(torch.minimum(v, self.vmax), -self.vmax)
        x = self.x + v
        out = (x < space.lower) | (x > space.upper)
        self.x, self.v = space.clamp(x), torch.where(out, torch.zeros_like(v), v)
        f, _ = self.solver.fitness(self.x, self.targets)
        self.pbest, self.pbest_f, self.improved = keep_better(self.pbest, self.pbest_f, self.x, f)

    def elite_opposition(self) -> None:
        """Eq. 14 on the elite personal bests, within the dynamic bounds of the elite group; an
        opposite point outside the joint ranges is redrawn inside those bounds."""
        p, space = self.solver.p, self.solver.space
        B, P, n = self.x.shape
        n_elite = max(1, math.ceil(p.elite_frac * P))
        elite_f, idx = self.pbest_f.topk(n_elite, dim=1, largest=False)
        elite = torch.gather(self.pbest, 1, idx[..., None].expand(-1, -1, n))
        a, b = elite.min(dim=1, keepdim=True).values, elite.max(dim=1, keepdim=True).values
        opp = self.rand(B, n_elite, 1) * (a + b) - elite
        outside = (opp < space.lower) | (opp > space.upper)
        opp = torch.where(outside, a + self.rand(B, n_elite, n) * (b - a), opp)
        opp_f, _ = self.solver.fitness(opp, self.targets)
        new_pb, new_f, take = keep_better(elite, elite_f, opp, opp_f)
        self.pbest = self.pbest.scatter(1, idx[..., None].expand(-1, -1, n), new_pb)
        self.pbest_f = self.pbest_f.scatter(1, idx, new_f)
        self.improved = self.improved.scatter(1, idx, torch.gather(self.improved, 1, idx) | take)

    def crossover(self, t: int) -> None:
        """Eqs. 20-21 update each particle's probability, eq. 15 crosses it with its personal best,
        eq. 16 keeps the better."""
        p = self.solver.p
        B, P, n = self.x.shape
        alpha = p.p0 * (1 - t / p.iterations)
        self.pc = torch.where(self.rand(B, P) < p.pr, self.rand(B, P), alpha * self.pc)
        child = torch.where(self.rand(B, P, n) < self.pc[..., None], self.x, self.pbest)
        child_f, _ = self.solver.fitness(child, self.targets)
        self.pbest, self.pbest_f, take = keep_better(self.pbest, self.pbest_f, child, child_f)
        self.improved = self.improved | take

    def update_best(self) -> None:
        i = self.pbest_f.argmin(dim=1)
        self.gbest = self.pbest[torch.arange(len(i)), i]

    def best_errors(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Position and orientation error of each target's global best."""
        _, err = self.solver.fitness(self.gbest.unsqueeze(1), self.targets)
        return err["position"][:, 0], err["orientation"][:, 0]
