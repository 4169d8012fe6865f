"""The execution rule of spec section 8, the checker's own: an action starts once its boom's previous
action and every action it is interlocked after have ended; a move keeps its planned duration, a drill
takes its drawn one. Vectorised over draws: actions are taken level by level of the dependency graph
(sequence and interlock edges), so the loop runs over the graph's depth, never over draws.

The draws of issue 27's targets: the spec durations; ``n`` draws with every hole's drilling uniform in
0.7-1.5x its spec time; every hole alone at 3x (the others at 1x); each boom in turn at 1.5x while the
others run at 0.7x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .actions import Actions, Interlocks

RANDOM = (0.7, 1.5)
STALL = 3.0
SLOW, QUICK = 1.5, 0.7


@dataclass
class Graph:
    levels: list[np.ndarray]  # actions, level by level (each after every action it depends on)
    preds: np.ndarray  # (n, width) actions each must wait for; n (a column of zeros) pads
    cycle: list[int] | None  # a deadlock: actions, each waiting for the next, the last for the first


def graph(acts: Actions, locks: Interlocks) -> Graph:
    n = len(acts)
    prev = acts.previous
    seq = np.flatnonzero(prev >= 0)
    before = np.concatenate([prev[seq], locks.before])
    after = np.concatenate([seq, locks.after])
    deg = np.bincount(after, minlength=n)
    width = max(int(deg.max()) if n else 0, 1)
    preds = np.full((n, width), n, np.int64)
    order = np.argsort(after, kind="stable")
    slot = np.arange(len(after)) - np.searchsorted(after[order], after[order])
    preds[after[order], slot] = before[order]
    succ_order = np.argsort(before, kind="stable")
    succ_start = np.searchsorted(before[succ_order], np.arange(n + 1))
    left, levels, done = deg.copy(), [], 0
    level = np.flatnonzero(left == 0)
    while len(level):  # Kahn's algorithm, one level at a time
        levels.append(level)
        done += len(level)
        lo, cnt = succ_start[level], succ_start[level + 1] - succ_start[level]
        at = np.repeat(lo - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))  # every level node's successors
        nxt = after[succ_order[at]]
        np.subtract.at(left, nxt, 1)
        level = np.unique(nxt[left[nxt] == 0])
    cycle = None
    if done < n:  # what is left waits, directly or not, on itself: walk back to a repeat
        stuck = left > 0
        u, seen = int(np.flatnonzero(stuck)[0]), []
        while u not in seen:
            seen.append(u)
            u = int(next(p for p in preds[u] if p < n and stuck[p]))
        cycle = seen[seen.index(u):]  # each waits for the next one, the last for the first
    return Graph(levels, preds, cycle)


def execute(g: Graph, duration: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end ``(draws, n)`` of every action under ``duration (draws, n)``."""
    d, n = duration.shape
    end = np.zeros((d, n + 1))  # column n: "nothing to wait for", ends at t = 0
    start = np.zeros((d, n))
    for level in g.levels:
        start[:, level] = end[:, g.preds[level]].max(-1)
        end[:, level] = start[:, level] + duration[:, level]
    return start, end[:, :n]


@dataclass
class Draws:
    labels: list[str]
    factor: np.ndarray  # (draws, holes): drilling time over its spec time
    holes: list[str]


def draws(holes: list[str], boom_of: np.ndarray, booms: list[str], n: int, seed: int, fixed: bool) -> Draws:
    """The nominal draw first; then ``n`` random ones; with ``fixed``, each hole alone at 3x and each
    boom slow while the others are quick (``boom_of``: the boom index that drills each hole)."""
    H = len(holes)
    parts, labels = [np.ones((1, H))], ["nominal (spec durations)"]
    rng = np.random.default_rng(seed)
    parts.append(rng.uniform(*RANDOM, (n, H)))
    labels += [f"random {i} (seed {seed})" for i in range(n)]
    if fixed:
        stall = np.ones((H, H))
        np.fill_diagonal(stall, STALL)
        parts.append(stall)
        labels += [f"hole {h} at {STALL:g}x" for h in holes]
        slow = np.where(boom_of[None, :] == np.arange(len(booms))[:, None], SLOW, QUICK)
        parts.append(slow)
        labels += [f"boom {b} at {SLOW:g}x, the others at {QUICK:g}x" for b in booms]
    return Draws(labels, np.concatenate(parts), list(holes))
