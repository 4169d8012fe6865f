"""The product solver: a trained network's answer refined to the exact pose, with the safety model
as a constraint, and an honest status for every hole.

1. **Start** from the network (CUIKM by default): one forward pass lands within millimetres of a
   solution that is usually clear of the tunnel and of the boom itself.
2. **Refine** in float64 by damped least squares (Levenberg-Marquardt) on stacked rows: the 6-D
   pose residual ``pose6(q) - P``, and for each clearance below ``margin`` a row
   ``w (c_k(q) - margin)``. The rows use the analytic geometric Jacobian of the collar and the
   preview point and the analytic clearance gradients (:meth:`SafetyModel.clearances_with_jacobians`),
   all from one forward pass; autograd is only the tests' oracle. The 2 redundant joints of an
   8-joint boom let the clearance rows push the boom clear without giving up the pose.
3. **More starts** for the holes that are not yet exact and clear: perturbations of the network's
   answer, then seeded random joint vectors, all in one batch; each start is refined with the
   safety rows and without them (the latter answers "can the pose be reached at all?").
4. **One status per hole**, from every candidate found, in this order:

   * ``ok``: hole-seeking error <= ``tol_mm`` and every clearance >= 0 (the safety distances hold);
   * ``inexact``: clear, but the error is between ``tol_mm`` and ``reach_tol_mm``;
   * ``unsafe``: exact, but every exact solution found violates a safety distance;
   * ``unreachable``: no start reached the pose within ``reach_tol_mm``, whatever the collisions.

   Every hole keeps its best joints and their clearances; nothing is dropped.

Joints whose range spans a full turn (jumbo8's boom rotation and roll-over) wrap around instead of
stopping at +-180 deg; the others are projected onto their limits.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import rule
from pipeline.geometry.collision import SAFETY_KINDS, SafetyModel
from pipeline.solvers.base import HoleTargets, JointSpace, Solver, SolveResult, Targets, tool_transform

STATUSES = ("ok", "inexact", "unsafe", "unreachable")


@dataclass(frozen=True)
class HybridSettings:
    """``benchmark.solvers.hybrid`` / ``solve.solver``: tolerances, budget and starts."""

    tol_mm: float = field(default=0.01, metadata=rule(gt=0))  # exact: hole-seeking error at most this
    reach_tol_mm: float = field(default=1.0, metadata=rule(gt=0))  # beyond it, a hole is unreachable
    max_iters: int = field(default=12, metadata=rule(ge=1))  # LM iterations per start
    damping: float = field(default=1e-3, metadata=rule(gt=0))
    margin: float = field(default=0.002, metadata=rule(ge=0))  # m kept beyond each safety distance
    clearance_weight: float = field(default=1.0, metadata=rule(gt=0))
    perturbed_starts: int = field(default=8, metadata=rule(ge=0))
    random_starts: int = field(default=16, metadata=rule(ge=0))
    perturb: float = field(default=0.05, metadata=rule(gt=0))  # start noise, fraction of each joint's range
    seed: int = field(default=0, metadata=rule(ge=0))
    # among ok solutions of a hole: the largest clearance, or the nearest to the start (least joint motion)
    prefer: str = field(default="clearance", metadata=rule(choices=("clearance", "start")))

    def __post_init__(self):
        if self.reach_tol_mm < self.tol_mm:
            raise ConfigError(f"hybrid: reach_tol_mm = {self.reach_tol_mm} must be >= tol_mm = {self.tol_mm}")


@dataclass
class Candidates:
    """Refined joints of one or more starts per hole, with what the status rules need."""

    q: torch.Tensor  # (N, n_joints)
    hole_error: torch.Tensor  # (N,) m
    clearances: torch.Tensor  # (N, 4) m, in SAFETY_KINDS order
    iterations: torch.Tensor  # (N,)


class HybridSolver(Solver):
    name = "hybrid"

    def __init__(self, boom, safety: SafetyModel, init: Solver | None, settings: HybridSettings = HybridSettings(),
                 name: str = "hybrid"):
        super().__init__(boom)
        if safety.boom is not boom:
            raise InputError(f"{name}: the safety model belongs to boom '{safety.boom.name}', not '{boom.name}'")
        self.safety, self.init, self.s, self.name = safety, init, settings, name
        self.space = JointSpace(boom)
        span = self.space.upper - self.space.lower
        self.wraps = self.space.revolute & (span >= 2 * math.pi - 1e-9)  # full-turn joints

    # ------------------------------------------------------------------ one LM run per start
    def project(self, x: torch.Tensor) -> torch.Tensor:
        lo, hi = self.space.lower.to(x), self.space.upper.to(x)
        wrapped = torch.remainder(x - lo, 2 * math.pi) + lo
        return torch.where(self.wraps.to(x.device), wrapped, torch.maximum(torch.minimum(x, hi), lo))

    def _rows(self, x: torch.Tensor, target: torch.Tensor, use_safety: bool):
        """Stacked residual ``(B, m)``, its Jacobian ``(B, m, n)``, hole error ``(B,)``, clearances ``(B, 4)``.

        Clearance gradients are computed only for the configurations with a clearance row active
        (below ``margin``): from a network's answer that is a small share, and the rest of the batch
        pays only for the clearance values."""
        boom, s = self.boom, self.s
        frames = boom.frames(self.space.full(x))
        r = boom.pose6_from_frames(frames) - target
        J = boom.pose6_jacobian(frames)[..., self.space.free]
        hole = 0.5 * (r[:, :3].norm(dim=-1) + r[:, 3:].norm(dim=-1))
        values = self.safety.clearances_from_frames(frames)
        c = torch.stack([values[k] for k in SAFETY_KINDS], dim=-1)
        if use_safety:
            active = c < s.margin
            w = s.clearance_weight * active.to(c.dtype)
            G = torch.zeros(*c.shape, self.space.n, dtype=c.dtype)
            rows = active.any(dim=-1).nonzero().flatten()
            if len(rows):
                _, grads = self.safety.clearances_with_jacobians(frames[rows])
                G[rows] = torch.stack([grads[k] for k in SAFETY_KINDS], dim=-2)[..., self.space.free]
            r = torch.cat([r, w * (c - s.margin)], dim=-1)
            J = torch.cat([J, w.unsqueeze(-1) * G], dim=-2)
        return r, J, hole, c

    def refine(self, q0: torch.Tensor, target: torch.Tensor, use_safety: bool) -> Candidates:
        """Levenberg-Marquardt from ``q0 (N, n_joints)`` towards ``target (N, 6)``; each start stops
        on its own once exact (and, with ``use_safety``, clear), so the batch shrinks as it goes."""
        s = self.s
        stop_tol = 1e-3 * s.tol_mm / 1000  # iterate well below the status tolerance: converged, not borderline
        N, n = len(q0), self.space.n
        x_out = self.project(q0[:, self.space.free].double())
        hole_out = torch.empty(N, dtype=torch.float64)
        c_out = torch.empty(N, len(SAFETY_KINDS), dtype=torch.float64)
        iters = torch.zeros(N, dtype=torch.long)
        idx = torch.arange(N)
        x, tgt = x_out, target.double()
        lam = torch.full((N,), s.damping, dtype=torch.float64)
        r, J, hole, c = self._rows(x, tgt, use_safety)
        cost = (r * r).sum(-1)
        eye = torch.eye(n, dtype=torch.float64)
        for _ in range(s.max_iters + 1):
            done = (hole <= stop_tol) & ((c >= 0).all(-1) if use_safety else True)
            if done.any() or _ == s.max_iters:
                fin = done if _ < s.max_iters else torch.ones_like(done)
                x_out[idx[fin]], hole_out[idx[fin]], c_out[idx[fin]] = x[fin], hole[fin], c[fin]
                keep = ~fin
                if not keep.any():
                    break
                idx, x, tgt, lam, r, J, hole, c, cost = (t[keep] for t in (idx, x, tgt, lam, r, J, hole, c, cost))
            JtJ = J.transpose(1, 2) @ J
            # Marquardt scaling: damping proportional to the diagonal treats metres and radians alike
            A = JtJ + lam[:, None, None] * (torch.diagonal(JtJ, dim1=1, dim2=2).unsqueeze(-1) * eye + 1e-9 * eye)
            step = torch.linalg.solve(A, -(J.transpose(1, 2) @ r.unsqueeze(-1))).squeeze(-1)
            x_new = self.project(x + step)
            r_new, J_new, hole_new, c_new = self._rows(x_new, tgt, use_safety)
            cost_new = (r_new * r_new).sum(-1)
            better = cost_new < cost
            b1, b2 = better[:, None], better[:, None, None]
            x, r, J = torch.where(b1, x_new, x), torch.where(b1, r_new, r), torch.where(b2, J_new, J)
            hole, c = torch.where(better, hole_new, hole), torch.where(b1, c_new, c)
            cost = torch.where(better, cost_new, cost)
            lam = torch.where(better, lam * 0.3, lam * 10.0).clamp(1e-12, 1e8)
            iters[idx] += 1
        return Candidates(self.space.full(x_out), hole_out, c_out, iters)

    # ------------------------------------------------------------------ statuses
    def rank(self, cand: Candidates, reference: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Status index (into STATUSES) and a score to minimise, per candidate: ok prefers the
        largest clearance (or, with ``prefer: start``, the least motion from ``reference``, in
        fractions of each joint's range), inexact the smallest error, unsafe the smallest violation."""
        tol, reach = self.s.tol_mm / 1000, self.s.reach_tol_mm / 1000
        worst = cand.clearances.min(dim=-1).values
        exact, clear = cand.hole_error <= tol, worst >= 0
        status = torch.full_like(cand.iterations, 3)
        status = torch.where(exact & ~clear, torch.full_like(status, 2), status)
        status = torch.where(clear & (cand.hole_error <= reach), torch.full_like(status, 1), status)
        status = torch.where(exact & clear, torch.full_like(status, 0), status)
        key = torch.where((status == 0) | (status == 2), -worst.clamp(-10, 10), cand.hole_error.clamp(max=1e3))
        if self.s.prefer == "start" and reference is not None:
            span = self.space.upper - self.space.lower
            motion = (((cand.q - reference)[:, self.space.free] / span) ** 2).sum(-1)
            key = torch.where(status == 0, motion, key)
        return status, status.double() * 1e6 + key

    def best_of(self, cand: Candidates, holes: int, reference: torch.Tensor) -> tuple[Candidates, torch.Tensor]:
        """The best of ``K`` candidates per hole (laid out hole-major, ``holes * K``); ``reference``
        ``(holes, n_joints)`` is each hole's start."""
        status, score = self.rank(cand, reference.repeat_interleave(len(cand.q) // holes, dim=0))
        k = len(status) // holes
        pick = score.reshape(holes, k).argmin(dim=1) + torch.arange(holes) * k
        it = cand.iterations.reshape(holes, k).sum(dim=1)
        return Candidates(cand.q[pick], cand.hole_error[pick], cand.clearances[pick], it), status[pick]

    def starts(self, q_net: torch.Tensor) -> torch.Tensor:
        """``(holes, K, n_joints)``: perturbations of the network's answers, then random joint vectors."""
        s, space = self.s, self.space
        g = torch.Generator().manual_seed(s.seed)
        H = len(q_net)
        x0 = q_net[:, space.free]
        noise = torch.randn(H, s.perturbed_starts, space.n, generator=g, dtype=torch.float64)
        perturbed = x0.unsqueeze(1) + s.perturb * (space.upper - space.lower) * noise
        rand = space.uniform((H, s.random_starts), g)
        return space.full(self.project(torch.cat([perturbed, rand], dim=1)))

    # ------------------------------------------------------------------ the solve
    def solve(self, targets: Targets) -> SolveResult:
        if not isinstance(targets, HoleTargets):
            raise InputError(f"{self.name}: solves holes (HoleTargets), got {type(targets).__name__}")
        if len(targets) == 0:
            raise InputError(f"{self.name}: no targets to solve")
        start = time.perf_counter()
        with torch.no_grad():
            pose = targets.pose.double()
            q_net = (self.init.solve(targets).q if self.init is not None
                     else (0.5 * (self.space.lower + self.space.upper)).expand(len(pose), -1))
            best = self.refine(self.space.full(q_net[:, self.space.free].double()), pose, use_safety=True)
            status, _ = self.rank(best)
            todo = (status != 0).nonzero().flatten()
            if len(todo) and self.s.perturbed_starts + self.s.random_starts > 0:
                best, status = self._more_starts(best, status, todo, q_net.double(), pose)
        wall = time.perf_counter() - start
        errors = targets.errors(tool_transform(self.boom, best.q))
        clearances = {k: best.clearances[:, i] for i, k in enumerate(SAFETY_KINDS)}
        return SolveResult(best.q, errors, best.iterations, wall,
                           status=[STATUSES[i] for i in status.tolist()], clearances=clearances)

    def _more_starts(self, best: Candidates, status: torch.Tensor, todo: torch.Tensor, q_net: torch.Tensor,
                     pose: torch.Tensor) -> tuple[Candidates, torch.Tensor]:
        """Every extra start of the holes ``todo``, with and without the safety rows, in one batch
        each; the best candidate per hole (the first pass's included) replaces the first pass's."""
        starts = self.starts(q_net[todo])
        H, K, n = starts.shape
        flat, tgt = starts.reshape(H * K, n), pose[todo].repeat_interleave(K, dim=0)
        safe = self.refine(flat, tgt, use_safety=True)
        free = self.refine(torch.cat([q_net[todo], flat]), torch.cat([pose[todo], tgt]), use_safety=False)
        free_first = Candidates(free.q[:H], free.hole_error[:H], free.clearances[:H], free.iterations[:H])
        free_rest = Candidates(free.q[H:], free.hole_error[H:], free.clearances[H:], free.iterations[H:])
        per_hole = [Candidates(best.q[todo], best.hole_error[todo], best.clearances[todo], best.iterations[todo]),
                    free_first]
        per_hole_k = [safe, free_rest]
        groups = [_reshape(c, H, 1) for c in per_hole] + [_reshape(c, H, K) for c in per_hole_k]
        merged = Candidates(*(torch.cat([getattr(g, f) for g in groups], dim=1).flatten(0, 1)
                              for f in ("q", "hole_error", "clearances", "iterations")))
        chosen, chosen_status = self.best_of(merged, H, q_net[todo])
        out = Candidates(best.q.clone(), best.hole_error.clone(), best.clearances.clone(), best.iterations.clone())
        out.q[todo], out.hole_error[todo], out.clearances[todo], out.iterations[todo] = (
            chosen.q, chosen.hole_error, chosen.clearances, chosen.iterations)
        status = status.clone()
        status[todo] = chosen_status
        return out, status


def _reshape(c: Candidates, holes: int, k: int) -> Candidates:
    """Hole-major ``(holes, k, ...)`` views of a flat candidate set."""
    return Candidates(c.q.reshape(holes, k, -1), c.hole_error.reshape(holes, k),
                      c.clearances.reshape(holes, k, -1), c.iterations.reshape(holes, k))
