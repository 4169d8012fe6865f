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
        if self.J is not None:
            if other.J is None:
                self.J = None  # stale rows otherwise: computed again when needed
            else:
                self.J[index] = other.J
        for k, v in self.extra.items():
            v[index] = other.extra[k]

    def where(self, mask: torch.Tensor, other: Evaluation) -> Evaluation:
        """``other`` where ``mask (B,)``, else this. A Jacobian missing on a side the mask picks from
        is dropped for every row (then computed again when a step needs it)."""
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
# done(x, evaluation, rows) -> (mask (b,), refreshed evaluation or None): which rows are finished; the
# callback may re-evaluate rows (in place) and then returns the evaluation
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
    B, n, dtype, device = x0.shape[0], x0.shape[-1], x0.dtype, x0.device  # every counter beside the rows
    x_out = x0.clone()
    trials = torch.zeros(B, dtype=torch.long, device=device)
    steps = torch.zeros(B, dtype=torch.long, device=device)
    jacobians = torch.zeros(B, dtype=torch.long, device=device)
    idx = torch.arange(B, device=device)
    x = x0
    if initial is not None:
        ev = initial
    else:
        ev = fun(x, idx, None)
    c = cost(ev.r)
    ev_out = Evaluation(ev.r.clone(), None, {k: v.clone() for k, v in ev.extra.items()})
    c_out = c.clone()
    # counters of the rows still running (compacted with them): every running row makes one trial per
    # pass, so its trials are the pass count; accepted steps and Jacobians differ per row
    n_steps = torch.zeros(B, dtype=torch.long, device=device)
    n_jac = torch.full((B,), int(initial is None and ev.J is not None), dtype=torch.long, device=device)
    lam = torch.full((B,), damping.initial, dtype=dtype, device=device)
    eye = torch.eye(n, dtype=dtype, device=device)
    floor = damping.floor * eye
    costs, accepted = [], []
    stopped = None  # rows a stopping rule of the last step ended (ftol, xtol, give_up)
    may_stop = ftol is not None or xtol is not None or math.isfinite(damping.give_up)
    it = 0
    while True:
        fin = stopped
        finished = None
        if cost_tol is not None:
            finished = c <= cost_tol
        if done is not None:
            mask, refreshed = done(x, ev, idx)
            if refreshed is not None:
                ev, c = refreshed, cost(refreshed.r)
            finished = mask if finished is None else finished | mask
        if finished is not None:
            fin = finished if fin is None else fin | finished
        out_of_budget = max_trials is not None and it >= max_trials
        if max_steps is not None:
            over = n_steps >= max_steps
            fin = over if fin is None else fin | over
        if groups is not None and finished is not None and not out_of_budget and finished.any():
            served = torch.zeros(int(groups.max()) + 1, dtype=torch.bool, device=device)
            served[groups[idx[finished]]] = True
            fin = fin | served[groups[idx]]
        if out_of_budget:
            fin = torch.ones(len(idx), dtype=torch.bool, device=device)
        if fin is not None and fin.any():
            rows = idx[fin]
            x_out[rows], c_out[rows] = x[fin], c[fin]
            trials[rows], steps[rows], jacobians[rows] = it, n_steps[fin], n_jac[fin]
            ev_out.r[rows] = ev.r[fin]
            for k, v in ev_out.extra.items():
                v[rows] = ev.extra[k][fin]
            keep = ~fin
            if not keep.any():
                break
            idx, x, lam, c, n_steps, n_jac = idx[keep], x[keep], lam[keep], c[keep], n_steps[keep], n_jac[keep]
            ev = ev.take(keep)
        if ev.J is None:
            ev.J = jac(x, idx)
            n_jac += 1
        J, r = ev.J, ev.r
        Jt = J.transpose(-1, -2)
        JtJ = Jt @ J
        D = torch.diagonal(JtJ, dim1=-2, dim2=-1).unsqueeze(-1) * eye + floor if damping.marquardt else eye
        step = torch.linalg.solve(JtJ + lam[:, None, None] * D, -(Jt @ r.unsqueeze(-1))).squeeze(-1)
        x_new = x + step if project is None else project(x + step)
        ev_new = fun(x_new, idx, ev)
        if ev_new.J is not None:
            n_jac += 1
        c_new = cost(ev_new.r)
        better = c_new < c  # NaN and inf never are
        it += 1
        n_steps += better
        if may_stop:  # an accepted step that gained (almost) nothing
            stopped = torch.zeros_like(better)
            if ftol is not None:
                stopped |= better & (c - c_new <= ftol * c)
            if xtol is not None:
                stopped |= better & (step.norm(dim=-1) <= xtol * (1 + x.norm(dim=-1)))
        x = torch.where(better[:, None], x_new, x)
        ev = ev.where(better, ev_new)
        c = torch.where(better, c_new, c)
        lam = torch.where(better, lam * damping.down, lam * damping.up).clamp(damping.lam_min, damping.lam_max)
        if may_stop:
            stopped |= ~better & (lam > damping.give_up)
        if record:
            full, acc = c_out.clone(), torch.zeros(B, dtype=torch.bool, device=device)
            full[idx], acc[idx] = c, better
            costs.append(full)
            accepted.append(acc)
    return Result(x_out, ev_out, c_out, trials, steps, jacobians, costs, accepted)
