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
        p, space = self.p, self.space
        g = torch.Generator().manual_seed(p.seed)
        B, P, n = len(targets), p.population, space.n
        lo, hi = space.lower, space.upper
        rand = lambda *shape: torch.rand(*shape, generator=g, dtype=torch.float64)  # noqa: E731
        vmax = torch.where(space.revolute, p.v_max_revolute, p.v_max_prismatic).double()
        span = hi - lo
        vmax = torch.minimum(vmax, span.clamp_min(1e-12))
        arange_b = torch.arange(B)

        x = space.uniform((B, P), g)
        v = (2 * rand(B, P, n) - 1) * vmax
        f, _ = self.fitness(x, targets)
        pbest, pbest_f = x.clone(), f.clone()
        improved = torch.zeros(B, P, dtype=torch.bool)
        pc = torch.full((B, P), p.p0, dtype=torch.float64)  # eq. 19: each particle carries its own p
        n_elite = max(1, math.ceil(p.elite_frac * P))

        def best():
            i = pbest_f.argmin(dim=1)
            return pbest[arange_b, i], pbest_f[arange_b, i]

        gbest, _ = best()
        _, err = self.fitness(gbest.unsqueeze(1), targets)
        pos_trace, ori_trace = [err["position"][:, 0]], [err["orientation"][:, 0]]
        iters = torch.full((B,), p.iterations, dtype=torch.long)
        done = torch.zeros(B, dtype=torch.bool)
        for t in range(1, p.iterations + 1):
            # inertia: eqs. 17-18 (adaptive) or linearly decreasing
            if p.adaptive_inertia:
                w = ((p.w_max - p.w_min) * improved.double().mean(dim=1) + p.w_min)[:, None, None]
            else:
                w = p.w_max - (p.w_max - p.w_min) * (t - 1) / max(p.iterations - 1, 1)
            # eqs. 12-13 with the velocity limit; a particle leaving the ranges is put back on the
            # bound with its velocity there zeroed
            v = w * v + p.c1 * rand(B, P, 1) * (pbest - x) + p.c2 * rand(B, P, 1) * (gbest[:, None] - x)
            v = torch.maximum(torch.minimum(v, vmax), -vmax)
            x = x + v
            out = (x < lo) | (x > hi)
            x, v = space.clamp(x), torch.where(out, torch.zeros_like(v), v)
            f, _ = self.fitness(x, targets)
            improved = f < pbest_f
            pbest = torch.where(improved[..., None], x, pbest)
            pbest_f = torch.where(improved, f, pbest_f)

            if p.opposition:  # eq. 14 on the elite personal bests, dynamic bounds of the elite group
                elite_f, idx = pbest_f.topk(n_elite, dim=1, largest=False)
                elite = torch.gather(pbest, 1, idx[..., None].expand(-1, -1, n))
                a, b = elite.min(dim=1, keepdim=True).values, elite.max(dim=1, keepdim=True).values
                k = rand(B, n_elite, 1)
                opp = k * (a + b) - elite
                outside = (opp < lo) | (opp > hi)
                opp = torch.where(outside, a + rand(B, n_elite, n) * (b - a), opp)
                opp_f, _ = self.fitness(opp, targets)
                take = opp_f < elite_f
                new_pb = torch.where(take[..., None], opp, elite)
                new_f = torch.where(take, opp_f, elite_f)
                pbest = pbest.scatter(1, idx[..., None].expand(-1, -1, n), new_pb)
                pbest_f = pbest_f.scatter(1, idx, new_f)
                improved = improved.scatter(1, idx, torch.gather(improved, 1, idx) | take)

            if p.crossover:  # eqs. 20-21 update p, eq. 15 crossover, eq. 16 keep the better
                alpha = p.p0 * (1 - t / p.iterations)
                pc = torch.where(rand(B, P) < p.pr, rand(B, P), alpha * pc)
                child = torch.where(rand(B, P, n) < pc[..., None], x, pbest)
                child_f, _ = self.fitness(child, targets)
                take = child_f < pbest_f
                pbest = torch.where(take[..., None], child, pbest)
                pbest_f = torch.where(take, child_f, pbest_f)
                improved = improved | take

            gbest, _ = best()
            _, err = self.fitness(gbest.unsqueeze(1), targets)
            pos_trace.append(err["position"][:, 0])
            ori_trace.append(err["orientation"][:, 0])
            if p.tol_pos > 0 and p.tol_ori > 0:
                reached = ~done & (err["position"][:, 0] <= p.tol_pos) & (err["orientation"][:, 0] <= p.tol_ori)
                iters = torch.where(reached, torch.full_like(iters, t), iters)
                done = done | reached
                if done.all():
                    break
        self.trace = SwarmTrace(torch.stack(pos_trace), torch.stack(ori_trace))
        return space.full(gbest), iters
