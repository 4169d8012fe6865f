"""The action dependency graph: edges ``(before, after)`` over ``n`` actions (sequence and interlocks).

A round runs to its end under the execution rule for every choice of durations exactly when this
graph has no cycle: then each action starts once its predecessors (finitely many, each ending in
finite time by induction along a topological order) have ended; a cycle's actions each wait for
another of the cycle, for ever (a deadlock).
"""

from __future__ import annotations

import numpy as np


def _adjacency(n: int, edges: np.ndarray) -> list[list[int]]:
    succ: list[list[int]] = [[] for _ in range(n)]
    for u, v in np.asarray(edges, int).reshape(-1, 2):
        succ[u].append(int(v))
    return succ


def topological(n: int, edges: np.ndarray) -> tuple[list[int], list[int] | None]:
    """A topological order (Kahn; lowest number first among the ready ones) and None, or the order of
    the nodes that can run and a cycle ``[v0, v1, ...]`` (edges v0 -> v1 -> ... -> v0) among the rest."""
    e = np.asarray(edges, int).reshape(-1, 2)
    indeg = np.bincount(e[:, 1], minlength=n) if len(e) else np.zeros(n, int)
    succ = _adjacency(n, e)
    ready = sorted(np.flatnonzero(indeg == 0).tolist(), reverse=True)
    order = []
    while ready:  # a stack of ready nodes: O(n + edges)
        u = ready.pop()
        order.append(u)
        for v in succ[u]:
            indeg[v] -= 1
            if indeg[v] == 0:
                ready.append(v)
    if len(order) == n:
        return order, None
    return order, _cycle_among(set(range(n)) - set(order), succ)


def _cycle_among(left: set[int], succ: list[list[int]]) -> list[int]:
    """Every node left by Kahn's order has a predecessor left too; walking predecessors repeats a node."""
    pred: dict[int, int] = {}
    for u in left:
        for v in succ[u]:
            if v in left:
                pred.setdefault(v, u)
    v, seen = min(left), []
    index: dict[int, int] = {}
    while v not in index:
        index[v] = len(seen)
        seen.append(v)
        v = pred[v]
    cycle = seen[index[v]:]
    return cycle[::-1]  # walked backwards along edges


def find_cycle(n: int, edges: np.ndarray) -> list[int] | None:
    return topological(n, edges)[1]


def reachable(n: int, edges: np.ndarray, order: list[int]) -> np.ndarray:
    """``(n, n)`` bool: ``r[u, v]`` iff a path of one or more edges leads from u to v (a DAG, ``order``
    topological); rows filled in reverse order, one vectorised OR per edge."""
    r = np.zeros((n, n), bool)
    succ = _adjacency(n, edges)
    for u in reversed(order):
        for v in succ[u]:
            r[u, v] = True
            r[u] |= r[v]
    return r


def reduce_edges(n: int, fixed: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """The rows of ``extra`` (interlocks) not implied by the others with ``fixed`` (the sequence): an
    edge u -> v is dropped when v is reachable from another successor of u. The transitive reduction of
    a DAG is unique and keeps reachability, so dropping all of them at once is safe."""
    fixed, extra = np.asarray(fixed, int).reshape(-1, 2), np.asarray(extra, int).reshape(-1, 2)
    if len(extra) == 0:
        return extra
    every = np.unique(np.concatenate([fixed, extra]), axis=0)
    order, cycle = topological(n, every)
    if cycle is not None:
        raise ValueError(f"reduce_edges: the graph has a cycle {cycle}")
    r = reachable(n, every, order)
    succ = _adjacency(n, every)
    keep = np.ones(len(extra), bool)
    for k, (u, v) in enumerate(extra):
        keep[k] = not any(w != v and r[w, v] for w in succ[u])
    return np.unique(extra[keep], axis=0)
