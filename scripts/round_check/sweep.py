"""Certified clearances over a round's whole timeline: self and tunnel per boom, boom-boom per pair.

Between two rows a boom's joints move linearly (the file's rule), so over a time interval inside one
row interval every point of a body moves at most ``tau = sum_j lever[body, j] |dq_j|``
(:meth:`BoomModel.lever`). Each boom's row intervals are cut so that tau <= ``spacing``; the union of
all booms' instants is the timeline (it holds every row time, so an interval between two of its
instants lies inside one row interval of every boom).

A certified floor over an interval follows from 1-Lipschitz distances: a distance between two bodies
changes by at most the sum of their travels, a body's distance to a tunnel surface by at most its own
travel (valid while the body stays at least that travel inside the profile, which every clearance
above the safety distance implies; otherwise no floor is claimed). That holds for the horseshoe and for
a profile of any shape alike (:mod:`.profile`: inside, a kind's distance is the distance from the axis
to that kind's segments, a distance to a set; the least over the kinds is the distance to the outline,
so an axis that far inside cannot leave it within that travel). With clearances c0, c1 at the ends
and travel tau over the interval, ``c(t) >= max(c0 - tau s, c1 - tau (1 - s))``, whose least value is
``min(c0, c1, (c0 + c1 - tau) / 2)``. Where that floor is short of the requirement (< 0) and the two
samples are not, the interval is split (``split`` parts, ``levels`` times) and judged again.

``pairs_only``: boom-boom keys alone (an executed window of two booms: their own clearances do not
depend on timing and are checked once on the trajectory file).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from .distance import SURFACES, segment_distance
from .files import BoomRows
from .settings import Settings


@dataclass
class Key:
    kind: str  # self | tunnel | boom
    booms: tuple[int, ...]
    body: int = -1
    surface: str = ""


@dataclass
class Result:
    keys: list[Key]
    sampled: np.ndarray  # (K,) least sampled clearance
    sampled_at: np.ndarray  # (K,) its time
    certified: np.ndarray  # (K,) least certified floor
    runs: list[tuple[int, float, float, float, float]] = field(default_factory=list)  # key, t0, t1, t_worst, worst
    unclear: list[tuple[int, float, float, float]] = field(default_factory=list)  # key, t0, t1, floor
    instants: int = 0
    refined: int = 0


class Sweep:
    def __init__(self, st: Settings, rows: dict[str, BoomRows], spacing: float, levels: int = 4, split: int = 8,
                 chunk: int = 20000, refine_cap: int = 2_000_000, pairs_only: bool = False):
        self.st, self.spacing, self.levels, self.split = st, spacing, levels, split
        self.own = not pairs_only  # self and tunnel keys
        self.chunk, self.cap = chunk, refine_cap
        self.rows = [rows[b.name] for b in st.booms]
        self.lever = [b.model.lever(b.model.d_extent(r.q)) for b, r in zip(st.booms, self.rows, strict=True)]
        self.keys: list[Key] = []
        self.tunnel_groups = []  # (key indices, offsets to raw distances, boom, body)
        for bi, b in enumerate(st.booms if self.own else ()):
            if b.model.self_pairs:
                self.keys.append(Key("self", (bi,)))
            for ki, body in enumerate(b.model.bodies):
                idx = []
                for s in SURFACES:
                    idx.append(len(self.keys))
                    self.keys.append(Key("tunnel", (bi,), ki, s))
                offsets = np.array([body.radius + st.safety[s] for s in SURFACES])
                self.tunnel_groups.append((np.array(idx), offsets, bi, ki))
        self.pairs = list(combinations(range(len(st.booms)), 2))
        for a, b in self.pairs:
            self.keys.append(Key("boom", (a, b)))

    # -- the timeline ------------------------------------------------------------------------------
    def base_instants(self) -> np.ndarray:
        parts = []
        for r, lev in zip(self.rows, self.lever, strict=True):
            tau = (np.abs(np.diff(r.q, axis=0)) @ lev.T).max(1) if len(r.t) > 1 else np.zeros(0)
            n = np.maximum(1, np.ceil(tau / self.spacing)).astype(np.int64)
            seg = np.repeat(np.arange(len(n)), n)
            within = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)
            dt = np.diff(r.t)
            parts += [r.t[seg] + dt[seg] * within / n[seg], r.t[-1:]]
        return np.unique(np.concatenate(parts))

    def states(self, t: np.ndarray) -> list[np.ndarray]:
        # before its first row or after its last a boom stands where that row puts it
        return [np.stack([np.interp(t, r.t, r.q[:, j]) for j in range(r.q.shape[1])], -1) for r in self.rows]

    # -- clearances and travels --------------------------------------------------------------------
    def measure(self, t: np.ndarray) -> np.ndarray:
        """``(n, K)`` clearances (distance minus what is required) at instants ``t``."""
        st, cols, pts = self.st, [], []
        for b, q in zip(st.booms, self.states(t), strict=True):
            m = b.model
            P = m.body_points(m.frames(q)) + b.base
            pts.append(P)
            if not self.own:
                continue
            if m.self_pairs:
                gaps = [segment_distance(P[:, i, 0], P[:, i, 1], P[:, j, 0], P[:, j, 1])
                        - m.bodies[i].radius - m.bodies[j].radius for i, j in m.self_pairs]
                cols.append(np.min(gaps, 0) - st.safety["self"])
            for ki, body in enumerate(m.bodies):
                s0, s1 = P[:, ki, 0], P[:, ki, 1]
                if body.skip_end > 0:  # the front of the feed works at the face: its checked part ends short
                    length = np.linalg.norm(s1 - s0, axis=-1, keepdims=True)
                    s1 = s0 + np.clip(1.0 - body.skip_end / np.maximum(length, 1e-12), 0.0, 1.0) * (s1 - s0)
                tun = st.tunnel.clearances(s0, s1)  # the horseshoe's or the profile's, per surface kind
                cols += [tun[:, k] - body.radius - st.safety[s] for k, s in enumerate(SURFACES)]
        for a, c in self.pairs:
            ma, mc, Pa, Pc = st.booms[a].model, st.booms[c].model, pts[a], pts[c]
            cols.append(np.min([segment_distance(Pa[:, i, 0], Pa[:, i, 1], Pc[:, j, 0], Pc[:, j, 1])
                                - bi.radius - bj.radius for i, bi in enumerate(ma.bodies)
                                for j, bj in enumerate(mc.bodies)], 0) - st.d_boom)
        return np.stack(cols, -1)

    def travel(self, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
        """``(n, K)``: a bound of how far the points a key involves move over [t0, t1] (inside one row
        interval of every boom, so joints move linearly there)."""
        per = [np.abs(q1 - q0) @ lev.T
               for q0, q1, lev in zip(self.states(t0), self.states(t1), self.lever, strict=True)]
        cols = []
        for bi, b in enumerate(self.st.booms if self.own else ()):
            if b.model.self_pairs:
                cols.append(np.max([per[bi][:, i] + per[bi][:, j] for i, j in b.model.self_pairs], 0))
            for ki in range(len(b.model.bodies)):
                cols += [per[bi][:, ki]] * len(SURFACES)
        for a, c in self.pairs:
            cols.append(per[a].max(1) + per[c].max(1))
        return np.stack(cols, -1)

    def floors(self, t0, t1, c0, c1) -> tuple[np.ndarray, np.ndarray]:
        """Floors ``(n, K)`` and where one is short of 0 though the samples are not (to refine)."""
        tau = self.travel(t0, t1)
        f = np.minimum(np.minimum(c0, c1), 0.5 * (c0 + c1 - tau))
        short = (f < 0) & (c0 >= 0) & (c1 >= 0)
        for idx, off, _, _ in self.tunnel_groups:
            inside = np.minimum((c0[:, idx] + off).min(1), (c1[:, idx] + off).min(1)) >= tau[:, idx[0]]
            f[np.ix_(~inside, idx)] = -np.inf  # the body may leave the profile: no Lipschitz floor
            # a body already sampled below one surface's clearance is a violation there: its other
            # surfaces get no floor, and refining them would not change the verdict
            broken = ((c0[:, idx] < 0) | (c1[:, idx] < 0)).any(1)
            short[np.ix_(broken, idx)] = False
        return f, short

    # -- the sweep ---------------------------------------------------------------------------------
    def run(self) -> Result:
        K = len(self.keys)
        res = Result(self.keys, np.full(K, np.inf), np.full(K, np.nan), np.full(K, np.inf))
        T = self.base_instants()
        res.instants = len(T)
        for s in range(0, max(len(T) - 1, 1), self.chunk):  # chunks of instants: memory stays bounded
            self._chunk(T[s:s + self.chunk + 1], res)
        return res

    def _sampled(self, t: np.ndarray, c: np.ndarray, res: Result) -> None:
        i = c.argmin(0)
        low = c[i, np.arange(c.shape[1])]
        better = low < res.sampled
        res.sampled[better], res.sampled_at[better] = low[better], t[i[better]]

    def _runs(self, t: np.ndarray, c: np.ndarray, res: Result) -> None:
        """Stretches of consecutive instants with a clearance below 0, per key."""
        bad = c < 0
        for k in np.flatnonzero(bad.any(0)):
            edges = np.diff(np.concatenate([[0], bad[:, k].astype(np.int8), [0]]))
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                w = a + int(c[a:b, k].argmin())
                res.runs.append((int(k), float(t[a]), float(t[b - 1]), float(t[w]), float(c[w, k])))

    def _chunk(self, t: np.ndarray, res: Result) -> None:
        K = len(self.keys)
        c = self.measure(t)
        self._sampled(t, c, res)
        self._runs(t, c, res)
        if len(t) < 2:
            res.certified = np.minimum(res.certified, c.min(0))
            return
        t0, t1, c0, c1 = t[:-1], t[1:], c[:-1], c[1:]
        for level in range(self.levels + 1):
            f, short = self.floors(t0, t1, c0, c1)
            sub = short.any(1)
            last = level == self.levels or sub.sum() * (self.split + 1) > self.cap
            if last:
                res.certified = np.minimum(res.certified, f.min(0))
                for i, k in np.argwhere(short):
                    res.unclear.append((int(k), float(t0[i]), float(t1[i]), float(f[i, k])))
                return
            if (~sub).any():
                res.certified = np.minimum(res.certified, f[~sub].min(0))
            if not sub.any():
                return
            a, b = t0[sub], t1[sub]
            tt = a[:, None] + (b - a)[:, None] * (np.arange(self.split + 1) / self.split)
            tt[:, -1] = b
            inner = tt[:, 1:-1]
            ci = self.measure(inner.ravel()).reshape(*inner.shape, -1)
            res.refined += inner.size
            self._sampled(inner.ravel(), ci.reshape(-1, ci.shape[-1]), res)
            # stretches within each refined interval: pad every interval so that none runs into the next
            pad_c = np.concatenate([np.full((len(a), 1, K), np.inf), ci], 1).reshape(-1, K)
            pad_t = np.concatenate([a[:, None], inner], 1).ravel()
            self._runs(pad_t, pad_c, res)
            full = np.concatenate([c0[sub][:, None], ci, c1[sub][:, None]], 1)
            t0, t1 = tt[:, :-1].ravel(), tt[:, 1:].ravel()
            c0, c1 = full[:, :-1].reshape(-1, full.shape[-1]), full[:, 1:].reshape(-1, full.shape[-1])
