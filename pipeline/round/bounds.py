"""The spec's lower bound of a round's makespan (section 7).

``max(longest single hole, (sum of drilling + sum over holes of the shortest move into the hole) / B)``

- a single hole: the fastest boom that can drill it leaves park, drills it and returns, so no
  round is shorter than the longest of these;
- every hole is entered once, by one of the booms that can drill it, from park or from another hole
  that boom can drill; B booms share the drilling and those entries, so one of them works at least
  the average;
- a hole only boom b can drill is b's work whatever the allocation: b drills all of its own holes,
  enters each (the shortest entry by b), and returns to park from some hole it can drill (the
  shortest such return), so no round is shorter than that sum for any boom. Without it a plan only
  one boom of two can drill reads half its true bound.

Holes no boom can drill are not part of the round and are left out. A round handed on from where
the booms stand (``Instance.start``) enters holes from each boom's start node instead of its park.
"""

from __future__ import annotations

import numpy as np

from pipeline.round.problem import Instance


def lower_bound(inst: Instance) -> float:
    H = inst.n_holes
    keep = inst.drillable
    if not keep.any():
        return 0.0
    drill = inst.drill_s
    ok = np.concatenate([inst.reach, np.ones((inst.n_booms, 1), bool)], axis=1)  # (B, H + 1), park allowed
    mv = np.where(ok[:, :, None] & ok[:, None, :], inst.move_s, np.inf)  # (B, from, to)
    first = inst.move_s[np.arange(inst.n_booms), inst.starts, :]  # (B, H + 1): out of each boom's start
    mv[:, H, :] = np.where(ok, first, np.inf)  # the round's first moves leave the start node (park unless handed on)
    mv[:, np.arange(H), np.arange(H)] = np.inf  # "from any other hole"
    into = mv[:, :, :H].min(axis=1).min(axis=0)  # shortest entry of each hole, any boom that can drill it
    single = np.where(inst.reach, first[:, :H] + drill + inst.move_s[:, :H, H], np.inf).min(axis=0)
    share = (drill[keep].sum() + into[keep].sum()) / inst.n_booms
    own = inst.reach & (inst.reach.sum(axis=0) == 1)  # (B, H): holes only boom b can drill
    into_by = mv[:, :, :H].min(axis=1)  # (B, H): boom b's shortest entry of each hole
    home = np.where(inst.reach, inst.move_s[:, :H, H], np.inf).min(axis=1)  # (B,): b's shortest return
    alone = np.where(own, drill + into_by, 0.0).sum(axis=1) + np.where(own.any(axis=1), home, 0.0)
    return float(max(single[keep].max(), share, alone.max()))
