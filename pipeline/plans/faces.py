"""Generated faces for the round benchmark: the demo face's designer at other densities, seeded.

:func:`generated_face` scales the demo face's spacings (stoping spacing and burden, contour and lifter
spacing, the minimum gap) by one factor, found by bisection so that the face has about ``n_holes``
holes (cut, relief, stoping, lifter and contour holes, every one drillable by the designer's own
checks), and moves the cut by a seeded offset, so two seeds give two different faces of one size.
"""

from __future__ import annotations

import numpy as np

from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SafetyModel
from pipeline.plans.demo_face import demo_face
from pipeline.plans.model import DrillPlan

BASE = {"stoping_spacing": 0.75, "burden": 0.7, "min_gap": 0.5, "contour_spacing": 0.55, "lifter_spacing": 0.75}


def generated_face(n_holes: int, seed: int, safety: SafetyModel, iters: int = 7) -> DrillPlan:
    """A face of about ``n_holes`` holes for ``safety``'s tunnel (module docstring)."""
    if n_holes < 20:
        raise ConfigError(f"generated face: n_holes = {n_holes!r}: expected at least 20 (cut, perimeter, stoping)")
    g = np.random.default_rng(seed)
    tunnel = safety.tunnel
    centre = (float(g.uniform(-0.25, 0.25)) * tunnel.width / 5.0, 1.6 + float(g.uniform(-0.2, 0.2)))

    def face(f):
        plan = demo_face(safety=safety, cut_centre=centre, **{k: v * f for k, v in BASE.items()})
        return plan

    lo, hi = 0.35, 2.5  # spacing factors: dense to sparse
    best = None
    for _ in range(iters):
        mid = (lo * hi) ** 0.5
        plan = face(mid)
        if best is None or abs(len(plan) - n_holes) < abs(len(best) - n_holes):
            best = plan
        if len(plan) == n_holes:
            break
        lo, hi = (mid, hi) if len(plan) > n_holes else (lo, mid)
    best.plan_id, best.name = f"face{n_holes}_s{seed}", f"generated face ~{n_holes} holes (seed {seed}): {best.name}"
    return best
