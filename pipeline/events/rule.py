"""The execution rule of docs/reference.md section 8, over a batch of drilling-time draws at once.

A boom starts an action as soon as its previous action has ended and every interlock of that action
holds (the action it waits for has ended); a move takes its planned duration, a drill whatever the
draw says. Actions are visited once in a topological order of the sequence and interlock edges, each
a vectorised max over the draws, so the cost is one pass over the actions whatever the number of
draws. A cycle in those edges is a deadlock for every draw: it is reported (its actions), and the
actions on it and after it never start (``inf``).

:func:`realised` turns one draw back into a :class:`pipeline.round.timeline.Timeline` (and the
instance with each hole's drilling phases scaled to the drawn duration), so the trajectory file of a
realised round is written by :func:`pipeline.round.tables.trajectory_table` and checked by
:func:`pipeline.round.timeline.scan` like a planned one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from pipeline.core.errors import Deadlock, InputError
from pipeline.events.actions import Actions
from pipeline.events.graph import topological
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline


@dataclass(frozen=True)
class Execution:
    """Per draw d and action k: ``start[d, k]``, ``end[d, k]``; per draw the makespan and, per boom,
    the time it stood waiting at interlocks (``standing[d, b]``: an action's start less its previous
    action's end, or less 0 for a boom's first action); ``deadlock``: the cycle's actions (global
    numbers), None when the round runs to its end."""

    start: np.ndarray
    end: np.ndarray
    makespan: np.ndarray
    standing: np.ndarray
    deadlock: list[int] | None = None


def durations(acts: Actions, drill_s) -> np.ndarray:
    """``(D, K)`` durations: planned for moves, ``drill_s[d, hole]`` for drills (``drill_s`` (H,) or
    (D, H), finite and > 0)."""
    d = np.asarray(drill_s, dtype=float)
    if d.ndim == 1:
        d = d[None]
    H = len(acts.hole_ids)
    if d.ndim != 2 or d.shape[1] != H:
        raise InputError(f"drilling durations: expected shape (H,) or (D, H) with H = {H}, got {np.shape(drill_s)}")
    drilled = acts.hole[acts.is_drill]
    if not np.all(np.isfinite(d[:, drilled])) or np.any(d[:, drilled] <= 0):
        raise InputError("drilling durations: every drilled hole needs a finite duration > 0")
    out = np.broadcast_to(acts.duration, (d.shape[0], len(acts))).copy()
    out[:, acts.is_drill] = d[:, drilled]
    return out


def execute(acts: Actions, interlocks: np.ndarray, drill_s) -> Execution:
    """Run the rule for every draw of ``drill_s`` with interlock edges ``(before, after)``."""
    dur = durations(acts, drill_s)
    D, K = dur.shape
    e = np.asarray(interlocks, int).reshape(-1, 2)
    seq = acts.sequence_edges()
    order, cycle = topological(K, np.concatenate([seq, e]))
    preds: list[list[int]] = [[] for _ in range(K)]
    for u, v in np.concatenate([seq, e]):
        preds[v].append(int(u))
    start, end = np.full((D, K), np.inf), np.full((D, K), np.inf)
    for k in order:  # one vectorised step per action, all draws at once
        p = preds[k]
        start[:, k] = end[:, p].max(1) if p else 0.0
        end[:, k] = start[:, k] + dur[:, k]
    prev = acts.previous
    ready = np.where(prev >= 0, end[:, np.clip(prev, 0, None)], 0.0)
    with np.errstate(invalid="ignore"):  # a deadlock leaves inf - inf: no wait to count there
        wait = np.nan_to_num(start - ready, nan=0.0)
    B = len(acts.booms)
    standing = np.zeros((D, B))
    for b in range(B):  # a few booms
        mine = acts.boom == b
        standing[:, b] = wait[:, mine].sum(1) if mine.any() else 0.0
    makespan = end.max(1) if K else np.zeros(D)
    return Execution(start, end, makespan, standing, cycle)


def realised(inst: Instance, acts: Actions, ex: Execution, draw: int = 0) -> tuple[Instance, Timeline]:
    """Draw ``draw`` as an instance (each drilled hole's three phases scaled to its drawn duration) and
    a timeline (routes, move starts and arrivals), for the trajectory table and the oracle's scan."""
    if ex.deadlock is not None:
        raise Deadlock(f"realised: the round deadlocks (cycle of actions {ex.deadlock}); no timeline")
    H = inst.n_holes
    phases = inst.phases.copy()
    drills = np.flatnonzero(acts.is_drill)
    holes = acts.hole[drills]
    planned = inst.drill_s[holes]
    scale = (ex.end[draw, drills] - ex.start[draw, drills]) / np.where(planned > 0, planned, 1.0)
    phases[holes] = inst.phases[holes] * scale[:, None]
    routes, ms, ar, ds = [], [], [], []
    for b in range(inst.n_booms):
        mine = acts.boom == b
        moves = np.flatnonzero(mine & ~acts.is_drill)
        routes.append(acts.hole[mine & acts.is_drill].tolist())
        ms.append(ex.start[draw, moves] if len(moves) else np.zeros(1))
        ar.append(ex.end[draw, moves] if len(moves) else np.zeros(1))
        ds.append(ex.start[draw, np.flatnonzero(mine & acts.is_drill)])
    start = None if inst.start is None else inst.starts
    return dataclasses.replace(inst, phases=phases), Timeline(routes, ms, ar, H, start=start, drill_start=ds)
