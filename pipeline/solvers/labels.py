"""The hybrid solver as the labelling function of Omega_sup (spec section 3): it maps hole poses to
joints for :mod:`pipeline.learning.supervised_set`, which takes it as a callable (learning sits
below solvers). The stages ``derive_box`` and ``generate`` build it here and pass it in.

The search is local, as an operator's would be: the home pose and perturbations of it, keeping the
ok solution that moves the joints least (``prefer: start``), without random restarts (see
:mod:`pipeline.learning.supervised_set` for why).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from pipeline.geometry.collision import SafetyModel
from pipeline.solvers.base import HoleTargets
from pipeline.solvers.hybrid import HybridSettings, HybridSolver

LOCAL_SEARCH = HybridSettings(prefer="start", random_starts=0, perturbed_starts=8)

Labeller = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]  # poses (n, 6) -> joints, found (n,)


def local_search(safety: SafetyModel, settings: HybridSettings = LOCAL_SEARCH) -> Labeller:
    """Poses -> the joints a local search finds and whether they are exact and clear (status ``ok``)."""
    solver = HybridSolver(safety.boom, safety, None, settings)

    def solve(pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        result = solver.solve(HoleTargets(pose, safety.boom.preview_depth))
        return result.q, torch.tensor([s == "ok" for s in result.status])

    return solve


def home_branch(safety: SafetyModel, settings: HybridSettings = LOCAL_SEARCH) -> Labeller:
    """Poses -> the solution a descent from the home pose reaches (pose only, no safety rows) and
    whether it reaches the pose within ``settings.tol_mm``."""
    solver = HybridSolver(safety.boom, safety, None, settings)

    def solve(pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        home = solver.space.full((0.5 * (solver.space.lower + solver.space.upper)).expand(len(pose), -1))
        found = solver.refine(home, pose, use_safety=False)
        return found.q, found.hole_error <= settings.tol_mm / 1000

    return solve
