"""The one batched damped least-squares solver (Levenberg-Marquardt) of the project.

``B`` independent problems ``min_x |r_b(x_b)|^2`` are solved side by side: every row keeps its own
damping ``lambda``, takes the step ``(J^T J + lambda D)^-1 (-J^T r)`` (``D = diag(J^T J) + floor I``
with Marquardt's scaling, which treats metres and radians alike; ``D = I`` without it), keeps the
trial point only where it lowers the cost (damping times ``down``; else times ``up``, within
``[lam_min, lam_max]``) and stops on its own. A row that stops leaves the batch, so the batch
shrinks as the easy rows finish and the hard ones pay alone.

The caller supplies the residual (and, eagerly or through ``jac``, the Jacobian) as a callback on
the rows still running; anything else a row carries with its point (clearances, flags) travels in
:attr:`Evaluation.extra` and is kept or replaced together with the point. Bounds hold by projection
after each step: a clamp onto ``[lower, upper]``, or a wrap for full-turn joints.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError


@dataclass
class Evaluation:
    """Residuals ``r (B, m)``, their Jacobian ``J (B, m, n)`` (None: not computed yet) and per-row
    tensors ``extra`` (first dimension ``B``) that belong to the same points."""

    r: torch.Tensor
    J: torch.Tensor | None = None
    extra: dict[str, torch.Tensor] = field(default_factory=dict)

    def take(self, index) -> Evaluation:
        return Evaluation(self.r[index], None if self.J is None else self.J[index],
                          {k: v[index] for k, v in self.extra.items()})

    def put(self, index, other: Evaluation) -> None:
        """Rows ``index`` replaced by ``other`` (in place)."""
        self.r[index] = other.r
        if self.J is not None and other.J is not None:
            self.J[index] = other.J
        for k, v in self.extra.items():
            v[index] = other.extra[k]

    def where(self, mask: torch.Tensor, other: Evaluation) -> Evaluation:
        """``other`` where ``mask (B,)``, else this; a Jacobian missing on either side is dropped
        where it would be needed (then recomputed lazily)."""
        def pick(a, b):
            return torch.where(mask.reshape(-1, *([1] * (a.ndim - 1))), b, a)
        if self.J is not None and other.J is not None:
            J = pick(self.J, other.J)
        elif self.J is not None and not mask.any():
            J = self.J
        elif other.J is not None and mask.all():
            J = other.J
        else:
            J = None
        return Evaluation(pick(self.r, other.r), J, {k: pick(v, other.extra[k]) for k, v in self.extra.items()})


# fun(x (b, n), rows (b,) original row indices, current evaluation of those rows or None at the start)
Residuals = Callable[[torch.Tensor, torch.Tensor, Evaluation | None], Evaluation]
Jacobian = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]  # jac(x, rows) -> (b, m, n)
# done(x, evaluation, rows) -> (mask (b,), evaluation): a row is finished; the callback may refresh the evaluation
Done = Callable[[torch.Tensor, Evaluation, torch.Tensor], tuple[torch.Tensor, Evaluation]]


@dataclass(frozen=True)
class Damping:
    """How the damping starts, moves and scales the step."""

    initial: float = 1e-3
    marquardt: bool = True  # D = diag(J^T J) + floor I; False: D = I (Levenberg, MATLAB trainlm)
    floor: float = 1e-9  # keeps D positive where a column of J vanishes
    down: float = 0.3  # on an accepted step
    up: float = 10.0  # on a rejected step
    lam_min: float = 1e-12
    lam_max: float = 1e8
    give_up: float = math.inf  # a row whose damping exceeds this after a rejected step stops

    def __post_init__(self):
        if not (self.initial > 0 and 0 < self.down < 1 < self.up and 0 <= self.lam_min <= self.lam_max
                and self.floor >= 0 and self.give_up > 0):
            raise ConfigError(f"least squares damping: need initial > 0, 0 < down < 1 < up, 0 <= lam_min <= "
                              f"lam_max, floor >= 0, give_up > 0; got {self}")


@dataclass
class Result:
    """Per row: final point ``x (B, n)``, its evaluation, cost, trial steps, accepted steps and
    Jacobian evaluations; ``costs``: the cost of every row after each trial (when recorded)."""

    x: torch.Tensor
    evaluation: Evaluation
    cost: torch.Tensor
    trials: torch.Tensor
    steps: torch.Tensor
    jacobians: torch.Tensor
    costs: list[torch.Tensor] = field(default_factory=list)
    accepted: list[torch.Tensor] = field(default_factory=list)


def sum_of_squares(r: torch.Tensor) -> torch.Tensor:
    return (r * r).sum(-1)


def projector(lower: torch.Tensor, upper: torch.Tensor, wrap: torch.Tensor | None = None
              ) -> Callable[[torch.Tensor], torch.Tensor]:
    """Projection onto ``[lower, upper]`` per column; columns in ``wrap`` (full turns) wrap around
    ``lower + (x - lower) mod 2 pi`` instead of stopping at the bound."""
    def project(x: torch.Tensor) -> torch.Tensor:
        lo, hi = lower.to(x), upper.to(x)
        clamped = torch.maximum(torch.minimum(x, hi), lo)
        if wrap is None:
            return clamped
        return torch.where(wrap.to(x.device), torch.remainder(x - lo, 2 * math.pi) + lo, clamped)
    return project


def least_squares(fun: Residuals, x0: torch.Tensor, *, jac: Jacobian | None = None,
                  damping: Damping = Damping(), max_trials: int | None = None, max_steps: int | None = None,
                  cost: Callable[[torch.Tensor], torch.Tensor] = sum_of_squares, cost_tol: float | None = None,
                  done: Done | None = None, ftol: float | None = None, xtol: float | None = None,
                  groups: torch.Tensor | None = None,
                  project: Callable[[torch.Tensor], torch.Tensor] | None = None,
                  initial: Evaluation | None = None, record: bool = False) -> Result:
    """Levenberg-Marquardt from ``x0 (B, n)``; every row stops on its own when

    * ``cost <= cost_tol``, or ``done`` says so (checked before each trial and after the last);
    * an accepted step lowered the cost by at most ``ftol * cost`` or was at most ``xtol (1 + |x|)`` long;
    * its damping passed ``damping.give_up`` on a rejected step;
    * it used ``max_trials`` trial steps or ``max_steps`` accepted ones;
    * another row of its ``groups (B,)`` label finished by ``cost_tol`` / ``done`` (one answer per group).

    ``fun`` returns the residuals at trial points (with the Jacobian, or without it, then ``jac``
    gives it once the point is accepted and needs a step); ``project`` maps each trial point back
    into the bounds (:func:`projector`). ``initial``: the evaluation at ``x0``, if already known.
    """
    if max_trials is None and max_steps is None:
        raise ConfigError("least squares: give max_trials or max_steps (else a row might never stop)")
    B = x0.shape[0]
    n = x0.shape[-1]
    dtype = x0.dtype
    x_out = x0.clone()
    trials = torch.zeros(B, dtype=torch.long)
    steps = torch.zeros(B, dtype=torch.long)
    jacobians = torch.zeros(B, dtype=torch.long)
    idx = torch.arange(B)
    x = x0
    if initial is not None:
        ev = initial
    else:
        ev = fun(x, idx, None)
        jacobians += int(ev.J is not None)
    c = cost(ev.r)
    ev_out = Evaluation(ev.r.clone(), None, {k: v.clone() for k, v in ev.extra.items()})
    c_out = c.clone()
    lam = torch.full((B,), damping.initial, dtype=dtype)
    eye = torch.eye(n, dtype=dtype)
    costs, accepted = [], []
    stopped = torch.zeros(B, dtype=torch.bool)  # by a stopping rule of the last step (ftol, xtol, give_up)
    while True:
        fin = stopped.clone()
        finished = torch.zeros_like(fin)
        if cost_tol is not None:
            finished |= c <= cost_tol
        if done is not None:
            mask, ev = done(x, ev, idx)
            c = cost(ev.r)
            finished |= mask
        budget = torch.zeros_like(fin)
        if max_trials is not None:
            budget |= trials[idx] >= max_trials
        if max_steps is not None:
            budget |= steps[idx] >= max_steps
        fin |= finished | budget
        if groups is not None and finished.any():
            served = torch.zeros(int(groups.max()) + 1, dtype=torch.bool)
            served[groups[idx[finished]]] = True
            fin |= served[groups[idx]]
        if fin.any():
            x_out[idx[fin]], c_out[idx[fin]] = x[fin], c[fin]
            ev_out.put(idx[fin], _without_jacobian(ev.take(fin)))
            keep = ~fin
            if not keep.any():
                break
            idx, x, lam, c, stopped = idx[keep], x[keep], lam[keep], c[keep], stopped[keep]
            ev = ev.take(keep)
        if ev.J is None:
            ev.J = jac(x, idx)
            jacobians[idx] += 1
        J, r = ev.J, ev.r
        JtJ = J.transpose(-1, -2) @ J
        D = (torch.diagonal(JtJ, dim1=-2, dim2=-1).unsqueeze(-1) * eye + damping.floor * eye
             if damping.marquardt else eye)
        step = torch.linalg.solve(JtJ + lam[:, None, None] * D, -(J.transpose(-1, -2) @ r.unsqueeze(-1))).squeeze(-1)
        x_new = x + step if project is None else project(x + step)
        ev_new = fun(x_new, idx, ev)
        if ev_new.J is not None:
            jacobians[idx] += 1
        c_new = cost(ev_new.r)
        better = c_new < c  # NaN and inf never are
        trials[idx] += 1
        steps[idx] += better.long()
        if ftol is not None or xtol is not None:
            small = torch.zeros_like(better)
            if ftol is not None:
                small |= c - c_new <= ftol * c
            if xtol is not None:
                small |= step.norm(dim=-1) <= xtol * (1 + x.norm(dim=-1))
            stopped = better & small
        x = torch.where(better[:, None], x_new, x)
        ev = ev.where(better, ev_new)
        c = torch.where(better, c_new, c)
        lam = torch.where(better, lam * damping.down, lam * damping.up).clamp(damping.lam_min, damping.lam_max)
        stopped = stopped | (~better & (lam > damping.give_up))
        if record:
            full = c_out.clone()
            full[idx] = c
            acc = torch.zeros(B, dtype=torch.bool)
            acc[idx] = better
            costs.append(full)
            accepted.append(acc)
    return Result(x_out, ev_out, c_out, trials, steps, jacobians, costs, accepted)


def _without_jacobian(ev: Evaluation) -> Evaluation:
    return Evaluation(ev.r, None, ev.extra)
