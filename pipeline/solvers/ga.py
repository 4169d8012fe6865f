"""Binary-coded GA with space decomposition (paper 003), vectorised over targets and sub-spaces.

GA (paper 003 sect. 3): each free joint is a ``bits``-bit gene; nonlinear rank selection and
tournament selection fill half the mating pool each; uniform and multi-point crossover (half
the pairs each); bit-flip mutation; inversion of a random gene segment. The best individual is
carried over (elitism; the paper does not say, decided here). Objective
``dE = a1*dN + a2*dP + a3*dQ`` with orientation error dN (deg), position error dP (mm) and
total joint rotation dQ = sum |q_i - home_i| (deg); fitness ``1 / (dE + 0.01)``.

Space decomposition (paper 003 sect. 2): sub-joint-space ``S_i`` lets only the last ``i`` joints
move (the others stay at home); each moving joint's range is split at home into two halves,
giving ``2^i`` sub-sub-spaces (126 for the 6 joints of rescue6). Their position workspaces are
bounding boxes from forward kinematics on a grid. A target is searched in every sub-sub-space
of the lowest level whose box contains it; when the best found there is worse than
``accept_mm`` / ``accept_deg`` the next level is searched too (the boxes over-approximate what
a level can reach; the paper has no such fallback, decided here).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import JointSpace, Solver, Targets, require, tool_transform


@dataclass(frozen=True)
class GAParams:
    population: int = 100
    generations: int = 200
    bits: int = 12
    crossover: float = 0.8
    mutation: float = 0.01  # per bit
    inversion: float = 0.1  # per individual
    rank_pressure: float = 0.05  # nonlinear ranking: P(rank r) ~ q (1 - q)^r
    tournament: int = 2
    points: int = 2  # multi-point crossover
    a_ori: float = 1.0  # per degree
    a_pos: float = 1.0  # per mm
    a_rot: float = 0.01  # per degree of total joint rotation
    decomposition: bool = False
    grid: int = 5  # forward-kinematics grid per moving joint for the workspace boxes
    box_margin_mm: float = 1.0
    accept_mm: float = 5.0
    accept_deg: float = 1.0
    seed: int = 0

    def __post_init__(self):
        require({
            "population >= 4 (even)": self.population >= 4 and self.population % 2 == 0,
            "generations >= 1": self.generations >= 1,
            "1 <= bits <= 30": 1 <= self.bits <= 30,
            "probabilities in [0, 1]": all(0 <= x <= 1 for x in (self.crossover, self.mutation, self.inversion)),
            "0 < rank_pressure < 1": 0 < self.rank_pressure < 1,
            "grid >= 2": self.grid >= 2,
        }, "GA parameters", self)


class GeneticIK(Solver):
    def __init__(self, boom: Boom, params: GAParams, locks: Mapping[str, float] | None = None, name: str = "ga"):
        super().__init__(boom)
        self.p = params
        self.space = JointSpace(boom, locks)
        self.name = name
        # home: zero where the range allows it, else mid-range (d3 of jumbo8 cannot be 0)
        self.home = torch.where(
            (self.space.lower <= 0) & (self.space.upper >= 0),
            torch.zeros_like(self.space.lower),
            0.5 * (self.space.lower + self.space.upper),
        )
        self._subspaces: dict[int, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        self.level: torch.Tensor | None = None  # level of each target's best solution (decomposition)
        self.accepted: torch.Tensor | None = None  # whether that solution met accept_mm / accept_deg

    # ------------------------------------------------------------------ objective
    def objective(self, x: torch.Tensor, targets: Targets) -> torch.Tensor:
        err = targets.errors(tool_transform(self.boom, self.space.full(x)))
        d_rot = torch.where(self.space.revolute, (x - self.home).abs(), torch.zeros_like(x)).sum(-1)
        p = self.p
        return (p.a_ori * torch.rad2deg(err["orientation"]) + p.a_pos * 1000 * err["position"]
                + p.a_rot * torch.rad2deg(d_rot))

    # ------------------------------------------------------------------ GA over boxes
    def decode(self, genes: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
        """Bits ``(..., n * bits)`` -> joints in ``[lo, hi]`` ``(..., n)``."""
        bits = self.p.bits
        weights = 2.0 ** torch.arange(bits - 1, -1, -1, dtype=torch.float64)
        ints = (genes.reshape(*genes.shape[:-1], -1, bits).double() * weights).sum(-1)
        return lo + (hi - lo) * ints / (2**bits - 1)

    def evolve(self, targets: Targets, lo: torch.Tensor, hi: torch.Tensor, g: torch.Generator):
        """One GA per row: target ``k`` searched in the box ``lo[k]..hi[k]``. Returns best joints
        ``(K, n)`` and their objective ``(K,)``."""
        p = self.p
        K, n = lo.shape
        N, L = p.population, n * p.bits
        lo_, hi_ = lo[:, None], hi[:, None]
        rows = torch.arange(K)[:, None]
        pop = torch.rand(K, N, L, generator=g) < 0.5
        rank_w = p.rank_pressure * (1 - p.rank_pressure) ** torch.arange(N, dtype=torch.float64)
        best_x, best_e = None, None
        for _ in range(p.generations):
            x = self.decode(pop, lo_, hi_)
            e = self.objective(x, targets)
            i = e.argmin(dim=1)
            gen_x, gen_e = x[torch.arange(K), i], e[torch.arange(K), i]
            if best_e is None:
                best_x, best_e, elite = gen_x, gen_e, pop[torch.arange(K), i]
            else:
                better = gen_e < best_e
                best_x = torch.where(better[:, None], gen_x, best_x)
                elite = torch.where(better[:, None], pop[torch.arange(K), i], elite)
                best_e = torch.where(better, gen_e, best_e)
            # selection: half by nonlinear ranking, half by tournament (lower dE = fitter)
            order = e.argsort(dim=1)
            picks = torch.multinomial(rank_w.expand(K, N), N // 2, replacement=True, generator=g)
            ranked = torch.gather(order, 1, picks)
            contenders = torch.randint(0, N, (K, N - N // 2, p.tournament), generator=g)
            winner = torch.gather(contenders, 2, torch.gather(e, 1, contenders.flatten(1)).reshape(contenders.shape)
                                  .argmin(dim=2, keepdim=True)).squeeze(2)
            parents = pop[rows, torch.cat([ranked, winner], dim=1)[:, torch.randperm(N, generator=g)]]
            a, b = parents[:, 0::2], parents[:, 1::2]
            # crossover: uniform for half the pairs, multi-point for the other half
            uniform_mask = torch.rand(K, N // 2, L, generator=g) < 0.5
            cuts = torch.randint(1, L, (K, N // 2, p.points), generator=g)
            seg = (torch.arange(L)[None, None, None] >= cuts[..., None]).sum(2) % 2 == 1
            use_uniform = torch.rand(K, N // 2, 1, generator=g) < 0.5
            mask = torch.where(use_uniform, uniform_mask, seg)
            cross = torch.rand(K, N // 2, 1, generator=g) < p.crossover
            mask = mask & cross
            child_a, child_b = torch.where(mask, b, a), torch.where(mask, a, b)
            pop = torch.cat([child_a, child_b], dim=1)
            pop = pop ^ (torch.rand(K, N, L, generator=g) < p.mutation)
            # inversion: reverse the genes between two random positions
            s, t = torch.randint(0, L, (2, K, N), generator=g).sort(dim=0).values
            j = torch.arange(L)[None, None]
            inside = (j >= s[..., None]) & (j <= t[..., None])
            src = torch.where(inside, s[..., None] + t[..., None] - j, j)
            inv = torch.rand(K, N, 1, generator=g) < p.inversion
            pop = torch.where(inv, torch.gather(pop, 2, src), pop)
            pop[:, 0] = elite  # elitism
        return best_x, best_e

    # ------------------------------------------------------------------ decomposition
    def subspaces(self, level: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sub-sub-spaces of ``level`` (the last ``level`` joints move): joint boxes ``lo, hi``
        ``(2^level, n)`` and position boxes ``(2^level, 2, 3)``; computed once, on first use."""
        if level not in self._subspaces:
            n, home = self.space.n, self.home
            moving = list(range(n - level, n))
            halves = list(itertools.product((0, 1), repeat=level))
            lo = home.expand(len(halves), n).clone()
            hi = home.expand(len(halves), n).clone()
            for k, half in enumerate(halves):
                for j, h in zip(moving, half, strict=True):
                    lo[k, j], hi[k, j] = (home[j], self.space.upper[j]) if h == 0 else (self.space.lower[j], home[j])
            u = torch.linspace(0, 1, self.p.grid, dtype=torch.float64)
            grid = torch.cartesian_prod(*[u] * level).reshape(-1, level)
            x = lo[:, None].expand(-1, len(grid), -1).clone()
            x[..., moving] = lo[:, None, moving] + grid[None] * (hi - lo)[:, None, moving]
            pos = tool_transform(self.boom, self.space.full(x))[..., :3, 3]
            box = torch.stack([pos.min(dim=1).values, pos.max(dim=1).values], dim=1)
            self._subspaces[level] = (lo, hi, box)
        return self._subspaces[level]

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        g = torch.Generator().manual_seed(self.p.seed)
        B, n = len(targets), self.space.n
        if not self.p.decomposition:
            x, _ = self.evolve(targets, self.space.lower.expand(B, n), self.space.upper.expand(B, n), g)
            self.level, self.accepted = torch.full((B,), n), torch.ones(B, dtype=torch.bool)
            return self.space.full(x), torch.full((B,), self.p.generations)
        pos = targets.position
        margin = self.p.box_margin_mm / 1000
        best_x = self.home.expand(B, n).clone()
        best_e = torch.full((B,), math.inf, dtype=torch.float64)
        level = torch.full((B,), -1)
        best_level = torch.full((B,), -1)
        runs = torch.zeros(B, dtype=torch.long)
        for i in range(1, n + 1):
            todo = level < 0
            lo, hi, box = self.subspaces(i)
            inside = ((pos[:, None] >= box[None, :, 0] - margin) & (pos[:, None] <= box[None, :, 1] + margin)).all(-1)
            pairs = (inside & todo[:, None]).nonzero()  # (target, sub-space) pairs searched at this level
            if len(pairs) == 0:
                continue
            t_idx, s_idx = pairs[:, 0], pairs[:, 1]
            x, e = self.evolve(targets.subset(t_idx), lo[s_idx], hi[s_idx], g)
            # best pair per target (scatter-min over the pairs of each target)
            e_best = torch.full((B,), math.inf, dtype=torch.float64).scatter_reduce(0, t_idx, e, "amin")
            winner = e == e_best[t_idx]
            w = winner.nonzero().flatten()
            first = torch.zeros(B, dtype=torch.long)
            first[t_idx[w]] = w  # any winning pair of each target (ties are equal in dE)
            has = torch.zeros(B, dtype=torch.bool)
            has[t_idx] = True
            improve = has & (e_best < best_e)
            best_x[improve] = x[first[improve]]
            best_e[improve] = e_best[improve]
            best_level[improve] = i
            runs += torch.bincount(t_idx, minlength=B) * self.p.generations
            err = targets.errors(tool_transform(self.boom, self.space.full(best_x)))
            ok = (has & (err["position"] * 1000 <= self.p.accept_mm)
                  & (torch.rad2deg(err["orientation"]) <= self.p.accept_deg))
            level = torch.where(ok & todo, torch.full_like(level, i), level)
            if (level >= 0).all():
                break
        self.level, self.accepted = best_level, level >= 0
        return self.space.full(best_x), runs
