"""Nominal-model IK for calibration: paper 000's NM (Levenberg-Marquardt) from the home pose, or
started from given joints so that the answer is the solution branch next to them."""

from __future__ import annotations

import torch

from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import HoleTargets, Solver, Targets, tool_transform
from pipeline.solvers.nm import NMSolver


class GivenStart(Solver):
    """A "solver" that answers the joints it was given: NM's starting point (``init``)."""

    name = "given"

    def __init__(self, boom: Boom, q: torch.Tensor):
        super().__init__(boom)
        self.q = q

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        return self.q.double(), torch.zeros(len(targets), dtype=torch.long)


def solve_holes(boom: Boom, pose6: torch.Tensor, start: torch.Tensor | None = None, max_iters: int = 100,
                tol: float = 1e-7, damping: float = 1e-3, restarts: int = 0, seed: int = 0, rounds_of: int = 10
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Joints ``(B, n_joints)`` reaching hole poses ``(B, 6)`` on ``boom``, and each hole's
    hole-seeking error (m). ``start``: NM starts there (else at mid-range, the home pose).

    NM iterates a whole batch until its last hole converges, and a hole at a joint limit can take
    all ``max_iters``; so NM runs in rounds of ``rounds_of`` iterations, each continuing only the
    holes not yet within ``tol`` from where the last round left them. ``restarts`` random restarts
    (from home) are then made for holes still not reached.
    """
    targets = HoleTargets(pose6, boom.preview_depth)
    q = None if start is None else start.double().clone()
    todo = torch.arange(len(targets))
    left = max_iters
    while left > 0 and len(todo):
        k = min(rounds_of, left)
        init = None if q is None else GivenStart(boom, q[todo])
        nm = NMSolver(boom, max_iters=k, tol=tol, damping=damping, name="nm", init=init)
        q_new = nm.solve(targets.subset(todo)).q
        q = q_new if q is None else q.index_copy(0, todo, q_new)
        with torch.no_grad():
            reached = targets.subset(todo).residual(tool_transform(boom, q_new)).norm(dim=-1) <= tol
        todo, left = todo[~reached], left - k
    if restarts and len(todo):
        nm = NMSolver(boom, max_iters=max_iters, tol=tol, damping=damping, restarts=restarts, seed=seed,
                                name="nm", init=GivenStart(boom, q[todo]))
        q = q.index_copy(0, todo, nm.solve(targets.subset(todo)).q)
    with torch.no_grad():
        return q, targets.errors(tool_transform(boom, q))["hole"]
