"""The execution rule of docs/reference.md section 8, over a batch of drilling-time draws at once.

A boom starts an action as soon as its previous action has ended and every interlock of that action
holds (the action it waits for has ended); a move takes its planned duration, a drill whatever the
draw says. Actions are visited once in a topological order of the sequence and interlock edges, each
a vectorised max over the draws, so the cost is one pass over the actions whatever the number of
draws. A cycle in those edges is a deadlock for every draw: it is reported (its actions), and the
actions on it and after it never start (``inf``).

**With zones** (docs/reference.md, section 9) which boom goes first depends on the draw, so there is no
one order of the actions: the rule runs by events instead, one step per action, each step vectorised
over the draws. In every draw each boom's next action has an earliest start (its previous action's
end, its interlocks' ends, and the time the zone it enters is left by another boom inside; unknown,
``inf``, while any of those has not started), and the earliest of them starts, the first boom of the
rig on a tie (the rule's tie-break for a zone). Starts are found in order of time, so what a later
step starts never makes an earlier one wrong. A draw in which no boom can start while actions are
left has deadlocked; its remaining actions never start. Without zones both ways give the same times
(tested); the pass over a fixed order is the one used then.

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
from pipeline.events.zones import Zones, check_zones
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline


@dataclass(frozen=True)
class Execution:
    """Per draw d and action k: ``start[d, k]``, ``end[d, k]``; per draw the makespan and, per boom,
    the time it stood waiting at interlocks and zones (``standing[d, b]``: an action's start less its
    previous action's end, or less 0 for a boom's first action), of it the time it stood before a zone
    another boom was inside (``standing_zone[d, b]``; the rest waited for an order, an interlock), and
    the time it stood at park after its last action until the round's end, nothing left to do
    (``idle_after[d, b]``; the whole makespan for a boom without actions); ``deadlock``: the cycle's
    actions (global numbers), or with zones the actions the booms stand before in the first draw that
    deadlocks, None when every draw runs to its end; ``deadlocked[d]``: whether draw d deadlocked."""

    start: np.ndarray
    end: np.ndarray
    makespan: np.ndarray
    standing: np.ndarray
    deadlock: list[int] | None = None
    deadlocked: np.ndarray | None = None
    standing_zone: np.ndarray | None = None
    idle_after: np.ndarray | None = None

    def __post_init__(self):
        if self.deadlocked is None:  # without zones a deadlock is every draw's
            object.__setattr__(self, "deadlocked", np.full(len(self.makespan), self.deadlock is not None))
        if self.standing_zone is None:
            object.__setattr__(self, "standing_zone", np.zeros_like(self.standing))
        if self.idle_after is None:
            object.__setattr__(self, "idle_after", np.zeros_like(self.standing))

    @property
    def standing_order(self) -> np.ndarray:
        """``(D, B)`` the standing spent waiting for interlocks (an order): the standing less the zones'."""
        return self.standing - self.standing_zone


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


def execute(acts: Actions, interlocks: np.ndarray, drill_s, zones: Zones | None = None) -> Execution:
    """Run the rule for every draw of ``drill_s`` with interlock edges ``(before, after)`` and ``zones``
    (none by default)."""
    dur = durations(acts, drill_s)
    e = np.asarray(interlocks, int).reshape(-1, 2)
    if zones is not None and len(zones):
        check_zones(acts, zones)
        start, end, deadlocked, stuck, zone_wait = _by_events(acts, e, dur, zones)
        return _execution(acts, start, end, stuck, deadlocked, zone_wait)
    return _in_order(acts, e, dur)


def _in_order(acts: Actions, e: np.ndarray, dur: np.ndarray) -> Execution:
    """The rule without zones: one pass over a topological order of the actions (module docstring)."""
    D, K = dur.shape
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
    return _execution(acts, start, end, cycle, None)


def _by_events(acts: Actions, e: np.ndarray, dur: np.ndarray, zones: Zones):
    """The rule with zones, event by event, all draws at once (module docstring): ``start, end`` (D, K)
    (``inf`` for an action that never starts), ``deadlocked`` (D,), the actions the booms stand before
    in the first draw that deadlocks (None if none does), and ``zone_wait`` (D, K): the part of each
    action's wait spent with another boom inside its zone, after its previous action and its
    interlocks' had ended."""
    D, K = dur.shape
    B = len(acts.booms)
    bounds = np.searchsorted(acts.boom, np.arange(B + 1))  # boom b's actions: bounds[b] .. bounds[b + 1] - 1
    # interlock predecessors, padded with K: a column whose end is -inf, so it never holds anything up
    n_pred = np.bincount(e[:, 1], minlength=K + 1) if len(e) else np.zeros(K + 1, int)
    preds = np.full((K + 1, max(1, int(n_pred.max()))), K)
    slot = np.zeros(K + 1, int)
    for u, v in e:  # the interlocks, once
        preds[v, slot[v]] = u
        slot[v] += 1
    names = zones.names
    zid = np.array([names.index(z) for z in zones.zone], int)
    Z = len(names)
    # the zones each action enters and leaves (it may begin or end sections of several), padded with Z:
    # a column that is never occupied
    enter_of: list[list[int]] = [[] for _ in range(K + 1)]
    leave_of: list[list[int]] = [[] for _ in range(K + 1)]
    for s, (f, la) in enumerate(zip(zones.first, zones.last, strict=True)):  # the sections, once
        enter_of[int(f)].append(int(zid[s]))
        leave_of[int(la)].append(int(zid[s]))
    width = max(1, *map(len, enter_of), *map(len, leave_of))
    enters, leaves = np.full((K + 1, width), Z), np.full((K + 1, width), Z)
    for k in range(K):
        enters[k, :len(enter_of[k])] = enter_of[k]
        leaves[k, :len(leave_of[k])] = leave_of[k]
    start = np.full((D, K), np.inf)
    end = np.full((D, K + 1), np.inf)
    end[:, K] = -np.inf
    nxt = np.tile(bounds[:-1], (D, 1))  # (D, B) each boom's next action
    free = np.zeros((D, B))  # when each boom's previous action ends
    occupant = np.full((D, Z + 1), -1)  # the boom inside (or last inside) each zone, -1: none yet
    left_at = np.full((D, Z + 1), np.inf)  # when that boom leaves it (inf: not known yet)
    rows = np.arange(D)
    booms = np.arange(B)[None, :, None]
    deadlocked = np.zeros(D, bool)
    zone_wait = np.zeros((D, K))
    for _ in range(K):  # one action starts in every draw at each step
        done = nxt >= bounds[1:][None, :]
        k = np.where(done, K, nxt)
        unheld = np.maximum(free, end[rows[:, None, None], preds[k]].max(2))
        z = enters[k]  # (D, B, width)
        other = occupant[rows[:, None, None], z]
        held = (other >= 0) & (other != booms)
        ready = np.maximum(unheld, np.where(held, left_at[rows[:, None, None], z], -np.inf).max(2))
        ready[done] = np.inf
        b = ready.argmin(1)  # the earliest, the rig's first boom on a tie
        t = ready[rows, b]
        go = np.isfinite(t)
        deadlocked |= ~go & ~done.all(1)
        d, b, t = rows[go], b[go], t[go]
        kk = nxt[d, b]
        zone_wait[d, kk] = t - unheld[d, b]
        start[d, kk] = t
        end[d, kk] = t + dur[d, kk]
        free[d, b] = end[d, kk]
        nxt[d, b] += 1
        for j in range(width):  # sections begun, then ended (a one-action section does both)
            m = enters[kk, j] < Z
            occupant[d[m], enters[kk[m], j]], left_at[d[m], enters[kk[m], j]] = b[m], np.inf
        for j in range(width):
            m = leaves[kk, j] < Z
            left_at[d[m], leaves[kk[m], j]] = end[d[m], kk[m]]
    stuck = None
    if deadlocked.any():
        d0 = int(np.flatnonzero(deadlocked)[0])
        stuck = [int(nxt[d0, b]) for b in range(B) if nxt[d0, b] < bounds[b + 1]]
    return start, end[:, :K], deadlocked, stuck, zone_wait


def _execution(acts: Actions, start: np.ndarray, end: np.ndarray, deadlock, deadlocked,
               zone_wait: np.ndarray | None = None) -> Execution:
    D, K = start.shape
    prev = acts.previous
    ready = np.where(prev >= 0, end[:, np.clip(prev, 0, None)], 0.0)
    with np.errstate(invalid="ignore"):  # a deadlock leaves inf - inf: no wait to count there
        wait = np.nan_to_num(start - ready, nan=0.0)
    B = len(acts.booms)
    standing, by_zone, idle = np.zeros((D, B)), np.zeros((D, B)), np.zeros((D, B))
    makespan = end.max(1) if K else np.zeros(D)
    for b in range(B):  # a few booms
        mine = acts.boom == b
        standing[:, b] = wait[:, mine].sum(1) if mine.any() else 0.0
        if zone_wait is not None and mine.any():
            by_zone[:, b] = zone_wait[:, mine].sum(1)
        with np.errstate(invalid="ignore"):  # a deadlocked draw: inf - inf
            idle[:, b] = np.nan_to_num(makespan - end[:, mine].max(1), nan=0.0) if mine.any() else makespan
    return Execution(start, end, makespan, standing, deadlock, deadlocked, by_zone, idle)


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
