"""The planner's own first rounds: every boom sweeping the face sideways, all in the same direction.

Booms of a jumbo stand side by side (bases along the rig's y). Two booms standing at holes conflict
mostly when their arms come near each other, which happens when the left boom works close to, or to
the right of, the right one (on the demo face with ``twin``, 38 % of the pairs of holes of L and R
break d_boom standing). A round that keeps each boom on its own side *and* moves them in step keeps
them apart: each boom takes a strip of the face across y, the booms' strips in the order of their
bases and of equal drilling time (:func:`balanced_strips`: the side of the centre line would leave
one boom of ``twin`` 3423 s of drilling and the other 2935 s on the demo face), and drills them in vertical bands of
``band_m`` across the face, every boom
from the same side of the face to the other (so the gap between two neighbours stays about the
width of a boom's share), up and down in turn within a band (short moves). Both directions are
seeds; the planner times them like every candidate and keeps what is best. These are starts for the
routing, not the reference's baselines (:mod:`pipeline.round.baselines` holds those).
"""

from __future__ import annotations

import numpy as np

from pipeline.round.baselines import stable_order
from pipeline.round.problem import Instance


def balanced_strips(inst: Instance) -> np.ndarray:
    """Boom index per hole (-1: no boom can drill it): holes in order of y, highest first, cut into
    contiguous strips of about equal drilling time, one per boom in order of base y (highest first).
    A hole the strip's boom cannot drill goes to the boom nearest in base y that can."""
    y, drill = inst.collars[:, 1], inst.drill_s
    by_y = np.argsort(-inst.base_y, kind="stable")
    ok = inst.drillable
    target = drill[ok].sum() / inst.n_booms
    out = np.full(inst.n_holes, -1)
    load = np.zeros(inst.n_booms)  # drilling seconds given to each boom so far (forced holes included)
    k = 0
    for h in np.argsort(-y, kind="stable"):
        if not ok[h]:
            continue
        while load[by_y[k]] >= target - 0.5 * drill[h] and k < inst.n_booms - 1:  # where it halves the error
            k += 1
        b = by_y[k]
        if not inst.reach[b, h]:
            able = np.flatnonzero(inst.reach[:, h])
            b = able[np.argmin(np.abs(inst.base_y[able] - inst.base_y[b]))]
        out[h] = b
        load[b] += drill[h]
    return out


def sweep_routes(inst: Instance, direction: int = -1, band_m: float = 1.0) -> list[list[int]]:
    """Each boom's holes (:func:`balanced_strips`) in bands of ``band_m`` along y, swept from +y to -y
    (``direction = -1``) or the other way, snaking in z within a band; precedence pairs kept."""
    alloc = balanced_strips(inst)
    y, z = inst.collars[:, 1], inst.collars[:, 2]
    key = -direction * y  # increasing along the sweep
    band = np.floor((key - key.min()) / band_m).astype(int) if len(key) else np.zeros(0, int)
    up = np.where(band % 2 == 0, z, -z)  # snake: up in even bands, down in odd ones
    routes = []
    for b in range(inst.n_booms):
        mine = np.flatnonzero(alloc == b)
        order = mine[np.lexsort((up[mine], band[mine]))]
        routes.append(stable_order([int(h) for h in order], inst.precedence))
    return routes


def clear_ends(routes: list[list[int]], park_blocked: np.ndarray, precedence=()) -> list[list[int]]:
    """Each route with a first hole its boom can reach from park, and a last one it can go home from,
    while the other booms stand at park (``park_blocked``: ``(B, H + 1, H + 1)``, the planner's
    :func:`pipeline.round.planner.park_blocked`; park is node H).

    A sweep starts each boom at one end of its strip; on a face where that end's move from park passes
    another boom's park (gen 150 ``trio``: boom M's first hole), no wait can part the two (the other
    boom stands there until it starts, or from its end), and the round falls back to one boom at a
    time, which meets the same move. The nearest hole along the route whose park move is clear is
    taken first (last) instead; the rest keep their order; precedence pairs kept."""
    out = []
    for b, r in enumerate(routes):
        r = list(r)
        H = park_blocked.shape[1] - 1
        if len(r) > 1 and park_blocked[b, H, r[0]]:
            k = next((k for k, h in enumerate(r) if not park_blocked[b, H, h]), None)
            if k is not None:
                r.insert(0, r.pop(k))
        if len(r) > 2 and park_blocked[b, r[-1], H]:
            k = next((k for k in range(len(r) - 1, 0, -1) if not park_blocked[b, r[k], H]), None)
            if k is not None:
                r.append(r.pop(k))
        out.append(stable_order(r, precedence))
    return out
