"""How Omega_sup is drawn and labelled: the working box (the range of each joint that face holes
actually use, docs/reference.md section 3). The labels themselves (sampled, home branch, continuation) are
:mod:`pipeline.data.hole_sets`' with the solvers of :mod:`pipeline.solvers.labels`.

Paper 000 labels its supervised set from "each joint's range of activity". A rig would take those
ranges from its logged joints; here they come from exact, collision-free solutions of holes drawn
like Omega_unsup, solved from the home pose (so no trained network is involved and the derivation
is reproducible), as the 1st-99th percentile of each joint.

The search is local, as an operator's would be: the home pose and perturbations of it, keeping the
ok solution that moves the joints least, without random restarts. With random restarts every hole
is solved, but the 1-2 % that need one land anywhere in the boom rotation and roll-over ranges
(+-180 deg) and would stretch the box over postures no rig uses; those holes are left out of the
statistics instead (their share is reported).

The solver comes in as a callable ``solve(poses) -> (joints, found)`` (learning sits below the
solvers; the stages build it with :mod:`pipeline.solvers.labels`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import torch

from pipeline.core.errors import InputError
from pipeline.data.holes import HoleSampling, sample_holes
from pipeline.geometry.collision import SafetyModel

Solve = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]  # poses (n, 6) -> joints (n, dof), found (n,)


def derive_working_box(safety: SafetyModel, sampling: HoleSampling, n: int, seed: int,
                       percentiles: tuple[float, float] = (1.0, 99.0), *,
                       solve: Solve) -> tuple[dict[str, list[float]], dict]:
    """Per free joint ``[lower, upper]`` (deg for revolute joints, m for prismatic ones, rounded to
    0.01), and statistics of the derivation. ``solve`` gives each hole's joints and whether they
    are exact and clear (e.g. :func:`pipeline.solvers.labels.local_search`)."""
    lo_pct, hi_pct = percentiles
    if not 0 <= lo_pct < hi_pct <= 100:
        raise InputError(f"derive_box.percentiles = {list(percentiles)}: expected 0 <= lower < upper <= 100")
    boom = safety.boom
    pose, _ = sample_holes(n, safety, sampling, seed)
    t0 = time.perf_counter()
    q, ok = solve(pose)
    solve_s = time.perf_counter() - t0
    if int(ok.sum()) < 100:
        raise InputError(f"derive_box: only {int(ok.sum())} of {n} holes solved exactly and clear; too few for "
                         "percentiles")
    q = q[ok]
    bounds = torch.quantile(q, torch.tensor([lo_pct / 100, hi_pct / 100], dtype=q.dtype), dim=0)
    box = {}
    for i, joint in enumerate(boom.joints):
        if joint.locked is not None:
            continue
        scale = 180 / math.pi if joint.revolute else 1.0
        lo, hi = (float(v) * scale for v in bounds[:, i])
        box[joint.name] = [math.floor(lo * 100) / 100, math.ceil(hi * 100) / 100]  # outward, so the box holds them
    stats = {"holes": n, "seed": seed, "ok": int(ok.sum()), "ok_share": float(ok.double().mean()),
             "percentiles": [lo_pct, hi_pct], "solve_s": solve_s}
    return box, stats
