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

from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.kinematics import Boom
from pipeline.optim.swarm import PSOParams, Swarm
from pipeline.solvers.base import JointSpace, Solver, Targets, require, tool_transform


@dataclass(frozen=True)
class SwarmIKSettings:
    """The PSO solver's settings (``solvers.<pso|eopso|ceopso>``): the swarm's (:class:`PSOParams`,
    flat keys here) and the IK's own (velocity limits per joint kind, fitness weights, tolerances, seed)."""

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
        require({"v_max > 0": self.v_max_revolute > 0 and self.v_max_prismatic > 0}, "PSO parameters", self)
        self.swarm  # noqa: B018 -- the swarm's own checks

    @property
    def swarm(self) -> PSOParams:
        """Paper 002's swarm: one random factor per particle, velocity lost on a bound."""
        return PSOParams(population=self.population, iterations=self.iterations, w_max=self.w_max, w_min=self.w_min,
                         c1=self.c1, c2=self.c2, per_coordinate=False, stop_at_bounds=True,
                         opposition=self.opposition, elite_frac=self.elite_frac, crossover=self.crossover, p0=self.p0,
                         pr=self.pr, adaptive_inertia=self.adaptive_inertia)


PRESETS = {
    "pso": {},
    "eopso": {"opposition": True},
    "ceopso": {"opposition": True, "crossover": True, "adaptive_inertia": True},
}


def params_for(variant: str, overrides: Mapping | None = None) -> SwarmIKSettings:
    if variant not in PRESETS:
        raise ConfigError(f"PSO variant {variant!r}: expected one of {sorted(PRESETS)}")
    return SwarmIKSettings(**{**PRESETS[variant], **dict(overrides or {})})


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
    """Paper 002's PSO family as an IK solver: one :class:`Swarm` per target over the joint ranges."""

    def __init__(self, boom: Boom, params: SwarmIKSettings, locks: Mapping[str, float] | None = None,
                 name: str = "pso"):
        super().__init__(boom)
        self.p = params
        self.space = JointSpace(boom, locks)
        self.name = name
        self.trace: SwarmTrace | None = None

    def fitness(self, x: torch.Tensor, targets: Targets) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        err = targets.errors(tool_transform(self.boom, self.space.full(x)))
        return self.p.w_pos * err["position"] + self.p.w_ori * err["orientation"], err

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        p, space = self.p, self.space
        vmax = torch.where(space.revolute, p.v_max_revolute, p.v_max_prismatic).double()
        vmax = torch.minimum(vmax, (space.upper - space.lower).clamp_min(1e-12))
        swarm = Swarm(lambda x: self.fitness(x, targets)[0], space.lower, space.upper, vmax, len(targets), p.swarm,
                      torch.Generator().manual_seed(p.seed))
        trace = [self.best_errors(swarm, targets)]
        iters = torch.full((len(targets),), p.iterations, dtype=torch.long)
        done = torch.zeros(len(targets), dtype=torch.bool)
        for t in range(1, p.iterations + 1):
            swarm.step(t)
            trace.append(self.best_errors(swarm, targets))
            if p.tol_pos > 0 and p.tol_ori > 0:
                reached = ~done & (trace[-1][0] <= p.tol_pos) & (trace[-1][1] <= p.tol_ori)
                iters = torch.where(reached, torch.full_like(iters, t), iters)
                done = done | reached
                if done.all():
                    break
        self.trace = SwarmTrace(torch.stack([e[0] for e in trace]), torch.stack([e[1] for e in trace]))
        return space.full(swarm.gbest), iters

    def best_errors(self, swarm: Swarm, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        """Position and orientation error of each target's global best."""
        _, err = self.fitness(swarm.gbest.unsqueeze(1), targets)
        return err["position"][:, 0], err["orientation"][:, 0]
