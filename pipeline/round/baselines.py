"""The reference's reference rounds (section 7), timed through the same timeline and conflict handling.

- ``naive``: each hole goes to the boom on its side of the centre line (y >= 0 to the boom at
  y > 0), drilled in the plan's row order. For a rig of more than two booms "its side" is the boom
  whose base is nearest in y (ties to the larger y), which is the reference's rule for twin and gives
  everything to the one boom of single. When that boom cannot drill the hole, the nearest-in-y boom
  that can takes it; a hole no boom can drill is left out (reported like the optimised round's).
- ``nearest``: the same allocation; each boom goes next to the nearest undrilled collar of its own
  (Euclidean, rig frame), starting from its drill end at park.

Both keep the precedence pairs: a boom's own holes are reordered as little as possible so that
every "i before j" of two holes of one boom holds (a stable topological order); pairs across booms
become waits in the timeline.
"""

from __future__ import annotations

import numpy as np

from pipeline.core.errors import ConfigError
from pipeline.round.problem import Instance


def side_allocation(inst: Instance) -> np.ndarray:
    """Boom index per hole (-1: no boom can drill it)."""
    if inst.collars is None or inst.base_y is None:
        raise ConfigError("round baselines need the collars and each boom's base y")
    y = inst.collars[:, 1]
    dist = np.abs(y[None, :] - inst.base_y[:, None])  # (B, H)
    # rank booms per hole: nearest in y, ties to the larger base y
    key = dist - 1e-9 * inst.base_y[:, None]
    key = np.where(inst.reach, key, np.inf)
    boom = key.argmin(axis=0)
    return np.where(inst.drillable, boom, -1)


def stable_order(seq: list[int], precedence) -> list[int]:
    """``seq`` reordered as little as possible so that every pair (i, j) within it has i before j."""
    inside = set(seq)
    preds = {h: {i for i, j in precedence if j == h and i in inside} for h in seq}
    out, done = [], set()
    while len(out) < len(seq):
        for h in seq:
            if h not in done and preds[h] <= done:
                out.append(h)
                done.add(h)
                break
        else:
            raise ConfigError("round.precedence holds a cycle among one boom's holes")
    return out


def naive_routes(inst: Instance) -> list[list[int]]:
    alloc = side_allocation(inst)
    return [stable_order([int(h) for h in np.flatnonzero(alloc == b)], inst.precedence) for b in range(inst.n_booms)]


def nearest_routes(inst: Instance) -> list[list[int]]:
    if inst.park_points is None:
        raise ConfigError("round baseline 'nearest' needs each boom's drill end at park (park_points)")
    alloc = side_allocation(inst)
    routes = []
    for b in range(inst.n_booms):
        todo = [int(h) for h in np.flatnonzero(alloc == b)]
        at, seq = inst.park_points[b], []
        while todo:
            d = np.linalg.norm(inst.collars[todo] - at, axis=1)
            h = todo.pop(int(np.argmin(d)))
            seq.append(h)
            at = inst.collars[h]
        routes.append(stable_order(seq, inst.precedence))
    return routes
