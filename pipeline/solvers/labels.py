"""The hybrid solver as the labelling function of Omega_sup (docs/reference.md, section 3): it maps hole poses to
joints for :mod:`pipeline.learning.supervised_set`, which takes it as a callable (learning sits
below solvers). The stages ``derive_box`` and ``generate`` build it here and pass it in.

The search is local, as an operator's would be: the home pose and perturbations of it, keeping the
ok solution that moves the joints least (``prefer: start``), without random restarts (see
:mod:`pipeline.learning.supervised_set` for why).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from pipeline.data.neighbours import nearest_in
from pipeline.geometry.collision import SafetyModel
from pipeline.solvers.base import HoleTargets
from pipeline.solvers.continuation import continuation_labels
from pipeline.solvers.hybrid import HybridSettings, HybridSolver

LOCAL_SEARCH = HybridSettings(prefer="start", random_starts=0, perturbed_starts=8)

Search = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]  # poses (n, 6) -> joints, ok (n,)
# poses (n, 6), LM iterations per refinement (None: the settings' max_iters) -> joints, found (n,)
Labeller = Callable[[torch.Tensor, int | None], tuple[torch.Tensor, torch.Tensor]]


def local_search(safety: SafetyModel, settings: HybridSettings = LOCAL_SEARCH) -> Search:
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

    def solve(pose: torch.Tensor, max_iters: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        home = solver.space.full((0.5 * (solver.space.lower + solver.space.upper)).expand(len(pose), -1))
        found = solver.refine(home, pose, use_safety=False, max_iters=max_iters)
        return found.q, found.hole_error <= settings.tol_mm / 1000

    return solve


def continuation(safety: SafetyModel, settings: HybridSettings = LOCAL_SEARCH, neighbours: int = 8,
                 seed_from_home: bool = True, clear: bool = False, rescue: bool = False) -> Labeller:
    """Poses -> joints by continuation (:mod:`pipeline.solvers.continuation`), and whether each
    reaches its pose within ``settings.tol_mm`` (and, with ``clear``, keeps every safety distance:
    the refinements then carry the hybrid's safety rows, so a label is a clear solution; without,
    they are pose only).

    ``seed_from_home``: every pose the descent from home solves is a seed (its home-branch label),
    and the walk labels only the rest, each from a solved neighbour; else only the 16 poses nearest
    the set's median pose are solved from home and the walk labels all others (it then drifts
    along the boom's redundancy from one wave to the next: measured in docs/design.md).

    ``rescue``: the poses the walk leaves (about 11 % of Omega_unsup-like holes, mostly high in the
    arch) are solved by the full hybrid (``solver`` defaults: random and deep starts, safety rows),
    each started from its nearest labelled pose's joints and keeping the ok solution nearest to
    them, and the walk then goes on from those."""
    solver = HybridSolver(safety.boom, safety, None, settings)
    full = HybridSolver(safety.boom, safety, None, HybridSettings(prefer="start"))
    home = solver.space.full((0.5 * (solver.space.lower + solver.space.upper))[None])[0]

    def solve(pose: torch.Tensor, max_iters: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        def refine(start: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            found = solver.refine(start, target, use_safety=clear, max_iters=max_iters)
            exact = found.hole_error <= settings.tol_mm / 1000
            return found.q, exact & (found.clearances >= 0).all(dim=-1) if clear else exact

        q0 = home.to(pose).expand(len(pose), -1).clone()
        seeds = torch.arange(len(pose)) if seed_from_home else \
            (pose - pose.median(dim=0).values).norm(dim=-1).argsort()[:16]
        solved0 = torch.zeros(len(pose), dtype=torch.bool)
        q0[seeds], solved0[seeds] = refine(q0[seeds], pose[seeds])
        q, exact, _ = continuation_labels(pose, refine, q0, solved0, neighbours)
        if rescue and not bool(exact.all()) and bool(exact.any()):
            miss, have = (~exact).nonzero().squeeze(-1), exact.nonzero().squeeze(-1)
            start = q[have[nearest_in(pose[have], pose[miss])]]
            result = full.solve(HoleTargets(pose[miss], safety.boom.preview_depth), start=start)
            ok = torch.tensor([status == "ok" for status in result.status], dtype=torch.bool)
            q[miss[ok]], exact[miss[ok]] = result.q[ok].to(q), True
            q, exact, _ = continuation_labels(pose, refine, q, exact, neighbours)
        return q, exact

    return solve
