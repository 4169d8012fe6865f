"""The planner's own proof that a round with zones is robust (docs/round.md, "Zones the planner chooses").

The round without zones is robust by the argument of :mod:`pipeline.events.interlocks`: its graph G0
orders every conflicting pair of actions, and its nominal timeline T0 was scanned clear at every
instant. Zones take some of G0's edges away (the orders inside a zone: graph G1, a subgraph) and add
mutual exclusion. Two things can then go wrong, and each is checked here for every entry order at once:

**A deadlock** (:func:`deadlock`). The booms' progress is a state: per boom how far it is (idle before
action k, or running it). A running boom may always finish; an idle one may start its next action when
every interlock before it has ended and no other boom is inside a zone it enters. Durations are free, so
every interleaving is possible; a state where no boom runs, none may start and actions are left is a
deadlock. Every transition moves one boom one step on, so the states, numbered with the booms as digits,
are visited in one increasing pass (compiled with numba): exact, for 2 or 3 booms of a few hundred
actions (a few million states); beyond ``max_states`` no proof is given and the planner keeps no zone.

**Two booms too close** (:func:`unsafe`). Every boom is at every instant in a *segment*: an action (its
sweep), or a *stand* between two actions (one configuration, in both their sweeps; at park before the
first and after the last). Two segments of two booms are safe together when

- they never overlap in time: one ends before the other starts in G1 (a path of the graph), or both lie
  inside one zone's sections (an action of a section, or a stand between two of them);
- or their configurations cannot come too close: the actions' sweeps do not conflict
  (:mod:`pipeline.events.conflicts`, certified); a stand's configuration lies in both neighbours'
  sweeps, so it is clear of whatever one of them is clear of;
- or a stand overlaps only in a way T0 showed clear: a boom that stands between ``p`` and ``n`` while
  the other's action ``y`` runs with ``p < y < n`` in G1 stands there throughout ``y`` in every
  execution, T0 included (G1's orders are G0's), and T0 was scanned clear; two stands whose
  neighbours are ordered ``p < n'`` and ``p' < n`` overlap in every execution, in T0 too.

Anything else is reported (the two segments named), and the planner drops the zone. Conflict is taken
per pair of actions, so the test is conservative: it may refuse a safe zone, never pass an unsafe one.
A boom that waits before a zone stands where its last action left it: that stand is a segment like any
other, so "the configuration a boom waits in is safe" is part of the same test.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from pipeline.events.actions import Actions
from pipeline.events.graph import reachable, topological
from pipeline.events.zones import Zones

MAX_STATES = 30_000_000  # 3 booms of ~150 actions each: 8 M; a fourth boom multiplies by hundreds


def closure(acts: Actions, edges: np.ndarray) -> np.ndarray:
    """``(K, K)`` bool: a path of one or more edges (the sequences and ``edges``) from u to v."""
    every = np.concatenate([acts.sequence_edges(), np.asarray(edges, int).reshape(-1, 2)])
    order, cycle = topological(len(acts), every)
    if cycle is not None:
        raise ValueError(f"closure: the graph has a cycle {cycle}")
    return reachable(len(acts), every, order)


def deadlock(acts: Actions, edges: np.ndarray, zones: Zones, max_states: int = MAX_STATES):
    """None when no interleaving of the round deadlocks (module docstring); else the actions the booms
    stand before in a deadlocked state (global numbers; -1 for a boom that is done). Raises ValueError
    when the state space is larger than ``max_states`` (no proof)."""
    B, K = len(acts.booms), len(acts)
    bounds = np.searchsorted(acts.boom, np.arange(B + 1))
    n = np.diff(bounds).astype(np.int64)
    states = int(np.prod(2 * n + 1, dtype=object))
    if states > max_states:
        raise ValueError(f"{states} states of progress (booms of {n.tolist()} actions) over max_states {max_states}")
    local = acts.index.astype(np.int64)
    need = np.zeros((K, B), np.int64)  # action g may start once boom j's progress is >= need[g, j]
    e = np.asarray(edges, int).reshape(-1, 2)
    cross = e[acts.boom[e[:, 0]] != acts.boom[e[:, 1]]]
    np.maximum.at(need, (cross[:, 1], acts.boom[cross[:, 0]]), 2 * (local[cross[:, 0]] + 1))
    # zone entries: action g is held while boom j's progress lies in [lo, hi] (inside its section)
    rows = []
    for name in zones.names:
        s = [i for i, z in enumerate(zones.zone) if z == name]
        for i in s:
            for o in s:
                if o != i:
                    f, la = int(zones.first[o]), int(zones.last[o])
                    rows.append((int(zones.first[i]), int(acts.boom[f]), 2 * local[f] + 1, 2 * local[la] + 1))
    rows.sort()
    blk = np.array(rows, np.int64).reshape(-1, 4)
    ptr = np.searchsorted(blk[:, 0], np.arange(K + 1)).astype(np.int64)
    s = _explore(n, bounds[:-1].astype(np.int64), need, ptr, blk[:, 1].copy(), blk[:, 2].copy(), blk[:, 3].copy())
    if s < 0:
        return None
    digits, left = [], s
    for b in reversed(range(B)):
        digits.append(left % (2 * n[b] + 1))
        left //= 2 * n[b] + 1
    c = digits[::-1]
    return [int(bounds[b] + c[b] // 2) if c[b] < 2 * n[b] else -1 for b in range(B)]


@njit(cache=True)
def _explore(n, base, need, ptr, blk_j, blk_lo, blk_hi):  # pragma: no cover - compiled
    B = len(n)
    dims = 2 * n + 1
    stride = np.ones(B, np.int64)
    for b in range(B - 2, -1, -1):
        stride[b] = stride[b + 1] * dims[b + 1]
    total = stride[0] * dims[0]
    reached = np.zeros(total, np.uint8)
    reached[0] = 1
    c = np.zeros(B, np.int64)
    for s in range(total):  # a transition adds a stride: increasing order visits every state after its parents
        if s > 0:  # c: the digits of s, one odometer step
            b = B - 1
            c[b] += 1
            while c[b] == dims[b]:
                c[b] = 0
                b -= 1
                c[b] += 1
        if reached[s] == 0:
            continue
        moved, done = False, True
        for b in range(B):
            if c[b] == 2 * n[b]:
                continue
            done = False
            ok = True
            if c[b] % 2 == 0:  # idle before action g: its interlocks and its zones
                g = base[b] + c[b] // 2
                for j in range(B):
                    if j != b and c[j] < need[g, j]:
                        ok = False
                for t in range(ptr[g], ptr[g + 1]):
                    if blk_lo[t] <= c[blk_j[t]] <= blk_hi[t]:
                        ok = False
            if ok:
                reached[s + stride[b]] = 1
                moved = True
        if not moved and not done:
            return s
    return -1


def _segments(acts: Actions):
    """Every boom's segments (module docstring): per segment its boom, the action it is (-1 for a
    stand), a stand's neighbours ``prev`` and ``next`` (-1: park), the action whose end it starts after
    and the one whose start ends it (-1: the round's start, its end)."""
    B = len(acts.booms)
    boom, act, prev, nxt = [], [], [], []
    for b in range(B):
        mine = np.flatnonzero(acts.boom == b)
        if not len(mine):
            continue
        stands_prev = np.concatenate([[-1], mine])
        stands_next = np.concatenate([mine, [-1]])
        boom += [b] * (2 * len(mine) + 1)
        act += list(mine) + [-1] * (len(mine) + 1)
        prev += [-1] * len(mine) + list(stands_prev)
        nxt += [-1] * len(mine) + list(stands_next)
    boom, act, prev, nxt = (np.asarray(x, int) for x in (boom, act, prev, nxt))
    is_act = act >= 0
    first = np.where(is_act, act, prev)  # the segment starts at E(first) (a stand) or S(act); -1: t = 0
    last = np.where(is_act, act, nxt)  # it ends at E(act) or S(next); -1: the round's end
    return boom, act, prev, nxt, is_act, first, last


def unsafe(acts: Actions, conflict: np.ndarray, r1: np.ndarray, zones: Zones) -> str | None:
    """None when every pair of segments of two booms is safe in the round with graph closure ``r1``
    (:func:`closure` of G1) and ``zones`` (module docstring); else the first unsafe pair, named.
    ``conflict``: ``(K, K)`` symmetric bool, the actions' sweeps conflict."""
    boom, act, prev, nxt, is_act, first, last = _segments(acts)
    S = len(boom)
    K = len(acts)
    # a segment's conflicts with every action: an action's own row; a stand's, both neighbours' (AND)
    ones = np.ones(K, bool)
    row_p = np.where((prev >= 0)[:, None], conflict[np.maximum(prev, 0)], ones[None])
    row_n = np.where((nxt >= 0)[:, None], conflict[np.maximum(nxt, 0)], ones[None])
    seg_conf = np.where(is_act[:, None], conflict[np.maximum(act, 0)], row_p & row_n)  # (S, K)
    # segment against segment: an action column, or a stand's two neighbours' columns
    col = lambda rows, k: np.where((k >= 0)[None, :], rows[:, np.maximum(k, 0)], True)  # noqa: E731
    pair_conf = np.where(is_act[None, :], col(seg_conf, act), col(seg_conf, prev) & col(seg_conf, nxt))
    other = boom[:, None] != boom[None, :]
    # ordered: X ends (at S/E of last[X]) before Y starts (after first[Y]), a path last[X] -> first[Y];
    # a stand's end S(n) precedes S(y) when n -> y, conservatively the same test
    has = (last[:, None] >= 0) & (first[None, :] >= 0)
    before = has & r1[np.maximum(last, 0)[:, None], np.maximum(first, 0)[None, :]]
    ordered = before | before.T
    inside = np.full(S, -1)  # the zone a segment lies inside (a section's action or a stand between two)
    names = zones.names
    for z, f, la in zip(zones.zone, zones.first, zones.last, strict=True):
        m = (is_act & (act >= f) & (act <= la)) | (~is_act & (prev >= f) & (nxt >= f) & (prev <= la) & (nxt <= la)
                                                   & (prev >= 0) & (nxt >= 0))
        inside[m] = names.index(z)
    exclusive = (inside[:, None] >= 0) & (inside[:, None] == inside[None, :])
    # covered by T0: a stand (p, n) throughout action y (p -> y -> n), or two stands that always co-stand
    stand = ~is_act

    def path(u, v):  # (S, S) r1[u, v], True where an end is the round's start or end
        ok = (u[:, None] < 0) | (v[None, :] < 0)
        return ok | r1[np.maximum(u, 0)[:, None], np.maximum(v, 0)[None, :]]

    throughout = stand[:, None] & is_act[None, :] & path(prev, act) & _path_to(r1, act, nxt)
    co_stand = stand[:, None] & stand[None, :] & path(prev, nxt) & path(prev, nxt).T
    covered = throughout | throughout.T | co_stand
    bad = other & pair_conf & ~ordered & ~exclusive & ~covered
    if not bad.any():
        return None
    i, j = map(int, np.argwhere(bad)[0])
    return f"{_say(acts, act[i], prev[i], nxt[i])} and {_say(acts, act[j], prev[j], nxt[j])} can overlap and come close"


def _path_to(r1: np.ndarray, act: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """``(S, S)``: for segment pairs (stand X, action Y): a path act[Y] -> nxt[X] (True where X has no
    next action: it stands at park to the end)."""
    ok = nxt[:, None] < 0
    return ok | r1[np.maximum(act, 0)[None, :], np.maximum(nxt, 0)[:, None]]


def _say(acts: Actions, a: int, p: int, n: int) -> str:
    if a >= 0:
        return acts.name(a)
    if p < 0:
        return f"boom {acts.booms[acts.boom[n]]} at park before {acts.name(n)}"
    if n < 0:
        return f"boom {acts.booms[acts.boom[p]]} at park after {acts.name(p)}"
    return f"boom {acts.booms[acts.boom[p]]} standing between {acts.name(p)} and {acts.name(n)}"
