"""The reference's lower bound of a round's makespan (section 7).

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
    if not inst.drillable.any():
        return 0.0
    ok = np.concatenate([inst.reach, np.ones((inst.n_booms, 1), bool)], axis=1)  # (B, H + 1), park allowed
    mv = np.where(ok[:, :, None] & ok[:, None, :], inst.move_s, np.inf)  # (B, from, to)
    first = inst.move_s[np.arange(inst.n_booms), inst.starts, :]  # (B, H + 1): out of each boom's start
    mv[:, H, :] = np.where(ok, first, np.inf)  # the round's first moves leave the start node (park unless handed on)
    mv[:, np.arange(H), np.arange(H)] = np.inf  # "from any other hole"
    return bound_from(inst.reach, inst.drill_s, first[:, :H], mv[:, :, :H].min(axis=1), inst.move_s[:, :H, H])


def bound_from(reach: np.ndarray, drill: np.ndarray, first: np.ndarray, into_by: np.ndarray,
               home: np.ndarray) -> float:
    """The bound from per boom and hole ``(B, H)`` seconds: ``first``, the shortest move from the boom's
    start node into the hole; ``into_by``, its shortest entry (from the start or another hole the boom
    can drill); ``home``, its shortest move back to park. Entries of holes a boom cannot drill are not read.
    With several joint solutions per hole (:mod:`pipeline.round.postures`), each is the least over them."""
    keep = reach.any(axis=0)
    if not keep.any():
        return 0.0
    single = np.where(reach, first + drill + home, np.inf).min(axis=0)
    into = np.where(reach, into_by, np.inf).min(axis=0)  # shortest entry of each hole, any boom that can drill it
    share = (drill[keep].sum() + into[keep].sum()) / reach.shape[0]
    own = reach & (reach.sum(axis=0) == 1)  # (B, H): holes only boom b can drill
    back = np.where(reach, home, np.inf).min(axis=1)  # (B,): b's shortest return
    alone = np.where(own, drill + into_by, 0.0).sum(axis=1) + np.where(own.any(axis=1), back, 0.0)
    return float(max(single[keep].max(), share, alone.max()))
