"""Deadlock over every interleaving: a round with zones explored state by state.

Whichever boom enters a zone first depends on the drilling durations, and so can a deadlock: through
several zones, or three booms, the pairwise test of :mod:`.certify` does not see every one, and the draws
meet only those their durations lead to. Here every order is tried. A state is each boom's progress, a
number ``p`` from 0 to ``2 n`` for a boom of ``n`` actions: ``2 i`` stands before its action ``i``,
``2 i + 1`` runs it. From a state, a running boom may finish (``p + 1``), and a standing one may start
its action (``p + 1``) when every action it waits for (its interlocks) has ended and no other boom is
inside a zone the action enters (that boom has started its section's first action and not ended its
last). Durations are free, so each of these moves can come first. A reachable state where no boom may
move while some has actions left is a deadlock. The states are explored breadth first, one level (the
sum of the progresses) at a time, every state of a level at once.
"""

from __future__ import annotations

import numpy as np

from .actions import Actions, Interlocks, Zones

MAX_STATES = 50_000_000


def explore(acts: Actions, locks: Interlocks, zones: Zones, max_states: int = MAX_STATES) -> dict:
    """``{"states": reachable states, "deadlock": the actions the booms stand before in one deadlocked
    state (names; None if none), "explored": False when the state space is over max_states}``."""
    B = len(acts.booms)
    n = np.diff(acts.first).astype(np.int64)
    radix = 2 * n + 1
    if float(np.prod(radix.astype(float))) > max_states:
        return {"explored": False, "states": None, "deadlock": None,
                "why": f"{int(np.prod(radix.astype(object)))} states over {max_states}"}
    weight = np.ones(B, np.int64)
    for b in range(B - 2, -1, -1):
        weight[b] = weight[b + 1] * radix[b + 1]
    K = len(acts)
    boom, local = acts.boom.astype(np.int64), acts.index.astype(np.int64)
    # per action: the actions it waits for (another boom's), padded with -1
    waits = [[] for _ in range(K)]
    for u, v in zip(locks.before, locks.after, strict=True):
        if boom[u] != boom[v]:
            waits[int(v)].append(int(u))
    # per action: the other booms' sections of each zone it enters, as (boom, first progress, last progress)
    guards = [[] for _ in range(K)]
    for s in range(len(zones)):
        for t in range(len(zones)):
            if zones.zone[s] == zones.zone[t] and zones.boom[s] != zones.boom[t]:
                f, la = int(zones.first[t]), int(zones.last[t])
                guards[int(zones.first[s])].append((int(boom[f]), 2 * int(local[f]) + 1, 2 * int(local[la]) + 1))
    wmax = max(1, max(map(len, waits)))
    gmax = max(1, max(map(len, guards)))
    W = np.full((K + 1, wmax), -1, np.int64)
    G = np.full((K + 1, gmax, 3), -1, np.int64)
    G[:, :, 1], G[:, :, 2] = 1, 0  # an empty guard: the interval [1, 0] holds no progress
    for k in range(K):
        W[k, :len(waits[k])] = waits[k]
        for j, gd in enumerate(guards[k]):
            G[k, j] = gd
    need_boom = np.where(W >= 0, boom[np.maximum(W, 0)], 0)
    need_at = np.where(W >= 0, 2 * (local[np.maximum(W, 0)] + 1), 0)  # ended: progress past it
    level = np.zeros(1, np.int64)
    states = 0
    while len(level):
        states += len(level)
        p = (level[:, None] // weight[None, :]) % radix[None, :]  # (F, B) progresses
        can = np.zeros_like(p, dtype=bool)
        for b in range(B):
            left = p[:, b] < 2 * n[b]
            running = left & (p[:, b] % 2 == 1)
            k = np.where(left & ~running, acts.first[b] + p[:, b] // 2, K)  # the action it would start
            ended = p[np.arange(len(p))[:, None], need_boom[k]] >= need_at[k]
            free = ~((G[k, :, 1] <= p[np.arange(len(p))[:, None], np.maximum(G[k, :, 0], 0)])
                     & (p[np.arange(len(p))[:, None], np.maximum(G[k, :, 0], 0)] <= G[k, :, 2])).any(1)
            can[:, b] = running | (left & ended.all(1) & free)
        stuck = ~can.any(1) & (p < 2 * n[None, :]).any(1)
        if stuck.any():
            q = p[int(np.flatnonzero(stuck)[0])]
            return {"explored": True, "states": states, "deadlock": [
                acts.name(int(acts.first[b] + q[b] // 2)) for b in range(B) if q[b] < 2 * n[b]]}
        level = np.unique((level[:, None] + weight[None, :])[can])
    return {"explored": True, "states": states, "deadlock": None}
