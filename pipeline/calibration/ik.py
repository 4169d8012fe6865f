"""Nominal-model IK for calibration: paper 000's NM (Levenberg-Marquardt) from the home pose, or
started from given joints so that the answer is the solution branch next to them."""

from __future__ import annotations

import torch

from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import HoleTargets, Solver, Targets
from pipeline.solvers.nm import LevenbergMarquardt


class GivenStart(Solver):
    """A "solver" that answers the joints it was given: NM's starting point (``init``)."""

    name = "given"

    def __init__(self, boom: Boom, q: torch.Tensor):
        super().__init__(boom)
        self.q = q

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        return self.q.double(), torch.zeros(len(targets), dtype=torch.long)


def solve_holes(boom: Boom, pose6: torch.Tensor, start: torch.Tensor | None = None, max_iters: int = 100,
                tol: float = 1e-7, damping: float = 1e-3, restarts: int = 3, seed: int = 0
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Joints ``(B, n_joints)`` reaching hole poses ``(B, 6)`` on ``boom``, and each hole's
    hole-seeking error (m). ``start``: NM starts there (else at mid-range); ``restarts`` random
    restarts are made only for holes not reached from the start."""
    init = None if start is None else GivenStart(boom, start)
    nm = LevenbergMarquardt(boom, max_iters=max_iters, tol=tol, damping=damping, restarts=restarts, seed=seed,
                            name="nm", init=init)
    result = nm.solve(HoleTargets(pose6, boom.preview_depth))
    return result.q, result.errors["hole"]
