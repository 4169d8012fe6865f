"""Episodes of a boom and the certified smallest distance between every pair of episodes of two booms,
whatever their relative timing.

A boom's timeline is a chain of episodes: pause 0, action 0, pause 1, ..., action n-1, pause n (a pause
stands at the configuration between two actions, at park before the first and after the last; a boom
without actions is one pause). Episode ``2p`` is pause p, ``2i + 1`` action i. An action's motion is its
rows, whenever it starts, so the set of configurations an episode passes through is fixed: the least
distance between two episodes' sets bounds the two booms' distance whenever the episodes overlap.

The floor is found by branch and bound over time cells: a cell [t0, t1] of an episode (planned clock)
is represented by the boom at one instant tm of it, and every body point of the boom at any instant
of the cell lies within ``r`` of where it is at tm, ``r`` the travel bound from tm to either end
(the cumulative lever-arm travel of :class:`round_check.sweep.Sweep`'s certificate, linear within a row
interval). The clamped capsule distance is 1-Lipschitz in both bodies' points, so over a pair of
cells the distance is at least the sampled one minus both cells' radii. A pair of cells whose bound is
below ``d_boom`` is split (the cell with the larger radius, at half its travel) until the bound
clears, a sample falls below (the episodes can come that close: the floor stays below), the radii
reach :data:`MIN_R` or the pairs :data:`CAP`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .actions import Actions
from .distance import segment_distance
from .files import BoomRows
from .settings import RigBoom

MIN_R = 1e-5  # m: a cell this small is not split further
CAP = 2_000_000  # cell pairs per level
CHUNK = 200_000  # cell pairs measured at once


def episode_windows(acts: Actions, b: int, r: BoomRows) -> np.ndarray:
    """``(2n + 1, 2)`` planned windows of boom b's episodes (a pause: the instant it stands at)."""
    k = np.arange(acts.first[b], acts.first[b + 1])
    n = len(k)
    w = np.empty((2 * n + 1, 2))
    at = np.concatenate([[r.t[0]], acts.t_end[k]])
    w[0::2] = at[:, None]
    w[1::2, 0], w[1::2, 1] = acts.t_start[k], acts.t_end[k]
    return w


def executed_windows(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Executed episode windows ``(draws, 2n + 1)`` each from one boom's action starts and ends
    ``(draws, n)``: a pause runs from the previous end (0 for the first) to the next start (for ever
    after the last)."""
    d = start.shape[0]
    s = np.concatenate([np.zeros((d, 1)), end], 1)
    e = np.concatenate([start, np.full((d, 1), np.inf)], 1)
    S, E = np.empty((d, 2 * start.shape[1] + 1)), np.empty((d, 2 * start.shape[1] + 1))
    S[:, 0::2], E[:, 0::2] = s, e
    S[:, 1::2], E[:, 1::2] = start, end
    return S, E


class Cells:
    """A boom's time cells, grown as they are split."""

    def __init__(self, boom: RigBoom, rows: BoomRows, windows: np.ndarray):
        self.boom, self.rows = boom, rows
        m = boom.model
        lever = m.lever(m.d_extent(rows.q))
        step = np.abs(np.diff(rows.q, axis=0)) @ lever.T  # (rows - 1, bodies) travel per row interval
        self.C = np.concatenate([np.zeros((1, step.shape[1])), np.cumsum(step, 0)])  # cumulative, per body
        self.S = np.concatenate([[0.0], np.cumsum(step.max(1))])  # a scalar measure of progress
        self.radius = np.array([bd.radius for bd in m.bodies])
        self.episodes = len(windows)  # episode i is cell i; the cells after them are children made by splits
        self.episode = np.arange(len(windows))
        self.t0, self.t1 = windows[:, 0].copy(), windows[:, 1].copy()
        self.children = np.full((len(windows), 2), -1, np.int64)
        self.tm, self.r, self.P = self._describe(self.t0, self.t1)

    def _at(self, t: np.ndarray, table: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, self.rows.t, table[:, j]) for j in range(table.shape[1])], -1)

    def _describe(self, t0, t1):
        t = self.rows.t
        s0, s1 = np.interp(t0, t, self.S), np.interp(t1, t, self.S)
        half = 0.5 * (s0 + s1)
        i = np.clip(np.searchsorted(self.S, half, side="left"), 1, len(t) - 1) if len(t) > 1 else np.zeros(len(t0), int)
        if len(t) > 1:
            den = self.S[i] - self.S[i - 1]
            frac = np.where(den > 0, (half - self.S[i - 1]) / np.where(den > 0, den, 1.0), 0.0)
            tm = t[i - 1] + frac * (t[i] - t[i - 1])
        else:
            tm = t0.copy()
        tm = np.where(s1 > s0, np.clip(tm, t0, t1), t0)
        c0, cm, c1 = self._at(t0, self.C), self._at(tm, self.C), self._at(t1, self.C)
        r = np.maximum(cm - c0, c1 - cm).clip(0.0)
        q = self._at(tm, self.rows.q)
        m = self.boom.model
        P = m.body_points(m.frames(q)) + self.boom.base
        return tm, r, P

    def split(self, cells: np.ndarray) -> np.ndarray:
        """``(len(cells), 2)`` children of ``cells`` (made once each)."""
        new = np.unique(cells[self.children[cells, 0] < 0])
        if len(new):
            mid = self.tm[new]
            t0 = np.concatenate([self.t0[new], mid])
            t1 = np.concatenate([mid, self.t1[new]])
            tm, r, P = self._describe(t0, t1)
            base = len(self.t0)
            self.t0, self.t1 = np.concatenate([self.t0, t0]), np.concatenate([self.t1, t1])
            self.tm = np.concatenate([self.tm, tm])
            self.r, self.P = np.concatenate([self.r, r]), np.concatenate([self.P, P])
            self.episode = np.concatenate([self.episode, self.episode[new], self.episode[new]])
            self.children = np.concatenate([self.children, np.full((2 * len(new), 2), -1, np.int64)])
            self.children[new, 0] = base + np.arange(len(new))
            self.children[new, 1] = base + len(new) + np.arange(len(new))
        return self.children[cells]


def _measure(A: Cells, B: Cells, ia: np.ndarray, ib: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sampled distance (capsules) and its certified bound over the two cells, per cell pair."""
    D, L = np.empty(len(ia)), np.empty(len(ia))
    for s in range(0, len(ia), CHUNK):
        a, b = ia[s:s + CHUNK], ib[s:s + CHUNK]
        Pa, Pb = A.P[a], B.P[b]
        d = np.stack([np.stack([segment_distance(Pa[:, i, 0], Pa[:, i, 1], Pb[:, j, 0], Pb[:, j, 1])
                                - A.radius[i] - B.radius[j] for j in range(len(B.radius))], -1)
                      for i in range(len(A.radius))], 1)  # (m, bodies of a, bodies of b)
        D[s:s + CHUNK] = d.min((1, 2))
        L[s:s + CHUNK] = (d - A.r[a][:, :, None] - B.r[b][:, None, :]).min((1, 2))
    return D, L


@dataclass
class Floors:
    floor: np.ndarray  # (episodes of a, episodes of b) certified least distance (m)
    below: np.ndarray  # (.., ..) a sampled distance under d_boom: the episodes can come that close
    pairs_measured: int
    least: np.ndarray | None = None  # (.., ..) least sampled distance (m): the episodes come at least that close
    least_at: np.ndarray | None = None  # (.., .., 2) planned-clock instants of a's and b's sample giving it


def floors(A: Cells, B: Cells, d_boom: float, max_levels: int = 60) -> Floors:
    # from the episodes' own cells, not from every cell: a boom's cells are shared by its pairs with the other
    # booms, and those an earlier pair split are children, reused when a split reaches them. Starting from all
    # of them (a third pair of a three-boom rig: millions of cell pairs) hit CAP at once and left every floor
    # unrefined, tens of metres below the truth.
    na, nb = A.episodes, B.episodes
    floor = np.full((na, nb), np.inf)
    below = np.zeros((na, nb), bool)
    least, least_at = np.full((na, nb), np.inf), np.full((na, nb, 2), np.nan)
    ia, ib = np.repeat(np.arange(na), nb), np.tile(np.arange(nb), na)
    measured = 0
    for level in range(max_levels + 1):
        D, L = _measure(A, B, ia, ib)
        measured += len(ia)
        ea, eb = A.episode[ia], B.episode[ib]
        np.logical_or.at(below, (ea, eb), D < d_boom)
        _keep_least(least, least_at, ea, eb, D, A.tm[ia], B.tm[ib])
        ra, rb = A.r[ia].max(1), B.r[ib].max(1)
        go = (L < d_boom) & ~below[ea, eb] & (np.maximum(ra, rb) > MIN_R)
        last = level == max_levels or go.sum() * 2 > CAP
        if last:
            go[:] = False
        np.minimum.at(floor, (ea[~go], eb[~go]), L[~go])  # leaves: their bound is final
        if not go.any():
            break
        ia, ib, ra, rb = ia[go], ib[go], ra[go], rb[go]
        on_a = ra >= rb  # split the wider cell of each pair
        ca, cb = np.repeat(ia[:, None], 2, 1), np.repeat(ib[:, None], 2, 1)
        ca[on_a], cb[~on_a] = A.split(ia[on_a]), B.split(ib[~on_a])
        ia, ib = ca.ravel(), cb.ravel()
    return Floors(floor, below, measured, least, least_at)


def least(A: Cells, B: Cells, ea: np.ndarray, eb: np.ndarray, tol: float = 1e-3, max_levels: int = 60
          ) -> tuple[float, float, tuple[int, int] | None, tuple[float, float] | None]:
    """The least distance over the episode pairs ``(ea[i], eb[i])``, to ``tol``: a certified lower bound, the
    least sampled distance (an upper bound: two configurations that far apart), the pair it is of and the
    two instants of the planned clock whose configurations give it. The
    same branch and bound as :func:`floors`, aimed at the minimum: a cell pair is split while its floor is
    more than ``tol`` below the least sample found so far (the cells' children are shared with it)."""
    if not len(ea):
        return np.inf, np.inf, None, None
    ia, ib = np.asarray(ea, np.int64), np.asarray(eb, np.int64)  # episode i is cell i (the first cells)
    ub, lb, at, when = np.inf, np.inf, None, None
    for level in range(max_levels + 1):
        D, L = _measure(A, B, ia, ib)
        k = int(D.argmin())
        if D[k] < ub:
            ub, at = float(D[k]), (int(A.episode[ia[k]]), int(B.episode[ib[k]]))
            when = (float(A.tm[ia[k]]), float(B.tm[ib[k]]))
        ra, rb = A.r[ia].max(1), B.r[ib].max(1)
        go = (L < ub - tol) & (np.maximum(ra, rb) > MIN_R)
        if level == max_levels or go.sum() * 2 > CAP:
            go[:] = False
        if (~go).any():
            lb = min(lb, float(L[~go].min()))
        if not go.any():
            break
        ia, ib, ra, rb = ia[go], ib[go], ra[go], rb[go]
        on_a = ra >= rb
        ca, cb = np.repeat(ia[:, None], 2, 1), np.repeat(ib[:, None], 2, 1)
        ca[on_a], cb[~on_a] = A.split(ia[on_a]), B.split(ib[~on_a])
        ia, ib = ca.ravel(), cb.ravel()
    return lb, ub, at, when


def _keep_least(least: np.ndarray, at: np.ndarray, ea: np.ndarray, eb: np.ndarray, D: np.ndarray, ta: np.ndarray,
                tb: np.ndarray) -> None:
    """Per episode pair, the least sampled distance so far and the two instants (planned clock) it was at."""
    better = np.flatnonzero(D < least[ea, eb])
    if not len(better):
        return
    key = ea[better] * least.shape[1] + eb[better]
    order = np.lexsort((D[better], key))  # by pair, then distance: the first of each pair is its least
    first = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    i = better[first]
    least[ea[i], eb[i]] = D[i]
    at[ea[i], eb[i], 0], at[ea[i], eb[i], 1] = ta[i], tb[i]
