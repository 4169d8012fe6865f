"""A tunnel of any cross-section (``tunnel=profile tunnel.file=<csv>``): the profile read and validated,
and a capsule axis' clearance to each of its surface kinds, with the checker's own 2-D geometry.

The file: columns ``y, z, surface``, the vertices of a closed polyline in the rig frame (m), in order
around the profile (either direction); the segment from vertex i to vertex i + 1 (the last to the
first) is a surface of vertex i's kind (ground, wall or arch). The tunnel is that cross-section extruded
along x. Refused (:class:`InputError`, naming the file and the row or segment): a missing column, fewer
than 3 vertices or more than ``tunnel.max_vertices``, a non-finite number, an unknown kind, a segment
shorter than :data:`MIN_SEGMENT_M`, a polyline that crosses itself (two non-adjacent segments meet, or
one folds back onto the next), a kind with no segment.

Distance of an axis (3-D segment P0-P1, its (y, z) projection a-b) to kind k: ``m_k``, the least 2-D
distance between a-b and any segment of kind k (0 where they cross); an end of a-b outside the polygon
adds ``-dist(end, outline)`` to the kind of the outline segment nearest to it (to each kind whose
segment is nearest, where two are: beyond a vertex where two kinds meet); ``v_k`` is the least of
these. Inside the profile ``v_k`` is the exact distance from the axis to kind k (1-Lipschitz in the
axis' points, which the sweep's certificate needs); an axis that leaves the profile crosses the outline
(``m_k = 0`` for the kind crossed) or has an end outside (a negative ``v_k``). Points on the outline
count as inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .distance import SURFACES
from .errors import InputError
from .paths import project_path

MIN_SEGMENT_M = 1e-6
COLUMNS = ["y", "z", "surface"]
_BLOCK = 1 << 20  # (batch x segments) elements per block: memory stays bounded for any batch


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _dot(u, v):
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]


def point_segment(p, a, b) -> np.ndarray:
    """Distance from points ``p`` to the closed segments [a, b] (2-D, broadcast over leading axes)."""
    d = b - a
    dd = _dot(d, d)
    u = np.clip(_dot(p - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    g = p - a - u[..., None] * d
    return np.sqrt(_dot(g, g))


def segments_meet(p, q, r, s) -> np.ndarray:
    """Whether the closed 2-D segments [p, q] and [r, s] share a point (broadcast over leading axes).

    Orientation signs: they meet when each segment's ends are not strictly on one side of the other's
    line; when all four points are on one line, when their extents overlap along both axes.
    """
    o1, o2 = _cross(q - p, r - p), _cross(q - p, s - p)
    o3, o4 = _cross(s - r, p - r), _cross(s - r, q - r)
    on_line = (o1 == 0) & (o2 == 0) & (o3 == 0) & (o4 == 0)
    overlap = np.ones(on_line.shape, bool)
    for k in (0, 1):
        overlap &= (np.maximum(p[..., k], q[..., k]) >= np.minimum(r[..., k], s[..., k])) & (
            np.maximum(r[..., k], s[..., k]) >= np.minimum(p[..., k], q[..., k]))
    general = (np.sign(o1) * np.sign(o2) <= 0) & (np.sign(o3) * np.sign(o4) <= 0)
    return np.where(on_line, overlap, general)


def segment_segment(p, q, r, s) -> np.ndarray:
    """Least distance between the closed 2-D segments [p, q] and [r, s]: 0 where they meet, else the
    least of the four end-to-other-segment distances (broadcast over leading axes)."""
    ends = np.minimum(np.minimum(point_segment(p, r, s), point_segment(q, r, s)),
                      np.minimum(point_segment(r, p, q), point_segment(s, p, q)))
    return np.where(segments_meet(p, q, r, s), 0.0, ends)


@dataclass
class Profile:
    """A validated profile: segments ``a[i] -> b[i]`` of kind ``SURFACES[kind[i]]``, sorted by kind
    (``starts``: where each kind's run begins, for one reduction per kind)."""

    file: str
    vertices: np.ndarray  # (n, 2) y, z as read
    a: np.ndarray  # (n, 2) segment starts, sorted by kind
    b: np.ndarray  # (n, 2) segment ends
    kind: np.ndarray  # (n,) index into SURFACES, ascending
    starts: np.ndarray  # (3,) first segment of each kind in a, b
    i0: np.ndarray  # (n,) the vertex each segment starts at
    i1: np.ndarray  # (n,) the vertex it ends at

    def __post_init__(self):
        self.d = self.b - self.a
        self.dd = _dot(self.d, self.d)

    def describe(self) -> dict:
        return {"kind": "profile", "file": self.file, "vertices": int(len(self.vertices)),
                "segments": {s: int((self.kind == k).sum()) for k, s in enumerate(SURFACES)}}

    def inside(self, p: np.ndarray) -> np.ndarray:
        """Points ``(..., 2)`` in the closed polygon (crossing number; the outline itself counts as inside)."""
        shape = p.shape[:-1]
        p = p.reshape(-1, 2)
        out = np.empty(len(p), bool)
        step = max(1, _BLOCK // len(self.a))
        for s in range(0, len(p), step):
            out[s:s + step] = self._inside(p[s:s + step])
        return out.reshape(shape)

    def _inside(self, p, gap=None):
        """``gap``: the points' distance to the outline, when known."""
        y, z = p[:, None, 0], p[:, None, 1]
        ay, az, by, bz = self.a[:, 0], self.a[:, 1], self.b[:, 0], self.b[:, 1]
        straddle = (az > z) != (bz > z)  # the segment crosses the horizontal line through p (half-open)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = ay + (z - az) * (by - ay) / (bz - az)
        odd = (straddle & (y < at)).sum(1) % 2 == 1
        gap = point_segment(p[:, None], self.a, self.b).min(1) if gap is None else gap
        return odd | (gap <= 1e-12)

    def clearances(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """``(..., 3)``: ``v_k`` of the axes [p0, p1] (rig frame, x y z; the profile does not depend on x)
        for each kind in :data:`SURFACES` order (definition above)."""
        shape = np.broadcast_shapes(p0.shape, p1.shape)[:-1]
        a = np.broadcast_to(p0[..., 1:], (*shape, 2)).reshape(-1, 2)
        b = np.broadcast_to(p1[..., 1:], (*shape, 2)).reshape(-1, 2)
        out = np.empty((len(a), len(SURFACES)))
        step = max(1, _BLOCK // len(self.a))
        for s in range(0, len(a), step):
            out[s:s + step] = self._clearances(a[s:s + step], b[s:s + step])
        return out.reshape(*shape, len(SURFACES))

    def _clearances(self, a, b):
        """The definition above, sharing the work between segments: each vertex's distance to the axis and
        side of its line once (a vertex ends two segments), each axis end's distance to every segment once
        (for ``m_k`` and for an end outside)."""
        d = b - a  # (N, 2) the axis, projected
        dd = _dot(d, d)
        rel = self.vertices[None] - a[:, None]  # (N, n, 2)
        u = np.clip(_dot(rel, d[:, None]) / np.where(dd > 0, dd, 1.0)[:, None], 0.0, 1.0)
        g = rel - u[..., None] * d[:, None]
        dv = np.sqrt(_dot(g, g))  # (N, n) vertex to axis
        side = np.sign(_cross(d[:, None], rel))  # (N, n) which side of the axis' line a vertex is on
        ends = []
        for e in (a, b):
            w = e[:, None] - self.a  # (N, S, 2)
            t = np.clip(_dot(w, self.d) / self.dd, 0.0, 1.0)
            g = w - t[..., None] * self.d
            ends.append((np.sqrt(_dot(g, g)), np.sign(_cross(self.d, w))))  # distance to, side of each segment
        (da, sa), (db, sb) = ends
        s0, s1 = side[:, self.i0], side[:, self.i1]
        meet = (s0 * s1 <= 0) & (sa * sb <= 0)
        on_line = (s0 == 0) & (s1 == 0) & (sa == 0) & (sb == 0)
        if on_line.any():  # all four on one line (or the axis a point on a segment's line): extents overlap?
            i, j = np.nonzero(on_line)
            meet[i, j] = segments_meet(a[i], b[i], self.a[j], self.b[j])
        m = np.where(meet, 0.0, np.minimum(np.minimum(da, db), np.minimum(dv[:, self.i0], dv[:, self.i1])))
        v = np.minimum.reduceat(m, self.starts, axis=1)  # (N, 3): each kind's segments are one run
        for e, de in ((a, da), (b, db)):
            dk = np.minimum.reduceat(de, self.starts, axis=1)  # (N, 3)
            gap = dk.min(1)
            out = ~self._inside(e, gap)
            # the nearest segment's kind; beyond a corner where two kinds meet both are nearest: each gets it
            near = out[:, None] & (dk <= gap[:, None] + 1e-9)
            v = np.where(near, np.minimum(v, -gap[:, None]), v)
        return v


def read_profile(value, max_vertices, root: Path) -> Profile:
    """The profile the settings name (``tunnel.file``; a relative path from ``root``, the project root)."""
    from .files import _numbers, _require, _table

    if not isinstance(value, str) or not value:
        raise InputError(f"settings: tunnel.file = {value!r}: expected the path of a profile CSV (tunnel=profile "
                         "tunnel.file=<path.csv>)")
    if isinstance(max_vertices, bool) or not isinstance(max_vertices, int) or max_vertices < 3:
        raise InputError(f"settings: tunnel.max_vertices = {max_vertices!r}: expected a whole number >= 3")
    path = project_path(value, root)
    where = f"tunnel.file {path}"
    df = _table(path, "tunnel profile (tunnel.file)")
    try:
        _require(df, COLUMNS, path)
    except InputError as e:
        raise InputError(f"tunnel.file {e}") from None
    n = len(df)
    if n < 3:
        raise InputError(f"{where}: {n} vertices; a closed profile needs at least 3")
    if n > max_vertices:
        raise InputError(f"{where}: {n} vertices, more than tunnel.max_vertices = {max_vertices}")
    try:
        yz = _numbers(df, ["y", "z"], path)
    except InputError as e:
        raise InputError(f"tunnel.file {e}") from None
    surface = df["surface"].str.strip().to_numpy(str)
    bad = ~np.isin(surface, SURFACES)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{where}: row {i + 2}: surface {str(surface[i])!r} is not one of {sorted(SURFACES)}"
                         f" ({int(bad.sum())} such row(s))")
    kind = np.array([SURFACES.index(s) for s in surface])
    nxt = np.roll(np.arange(n), -1)

    def seg(i):
        return f"segment {i} (rows {i + 2}-{nxt[i] + 2})"

    a, b = yz, yz[nxt]
    length = np.linalg.norm(b - a, axis=1)
    short = np.flatnonzero(length < MIN_SEGMENT_M)
    if len(short):
        i = int(short[0])
        raise InputError(f"{where}: {seg(i)} is {length[i]:.3g} m long, shorter than {MIN_SEGMENT_M:g} m (a repeated "
                         f"vertex?; {len(short)} such segment(s))")
    # a fold: a segment turning straight back over the one before it (adjacent segments overlapping)
    d0, d1 = b - a, b[nxt] - a[nxt]
    fold = (np.abs(_cross(d0, d1)) <= 1e-12 * length * length[nxt]) & (_dot(d0, d1) < 0)
    if fold.any():
        i = int(np.flatnonzero(fold)[0])
        raise InputError(f"{where}: the polyline crosses itself: {seg(int(nxt[i]))} folds back over {seg(i)}")
    # non-adjacent segments that meet, in blocks of rows (at most max_vertices^2 pairs)
    step = max(1, _BLOCK // n)
    for s in range(0, n, step):
        i = np.arange(s, min(n, s + step))[:, None]
        j = np.arange(n)[None, :]
        gap = (j - i) % n
        meet = segments_meet(a[i[:, 0], None], b[i[:, 0], None], a[None], b[None]) & (gap > 1) & (gap < n - 1)
        if meet.any():
            p, q = np.argwhere(meet)[0]
            p = int(i[p, 0])
            raise InputError(f"{where}: the polyline crosses itself: {seg(p)} meets {seg(int(q))}")
    missing = [s for k, s in enumerate(SURFACES) if not (kind == k).any()]
    if missing:
        raise InputError(f"{where}: no segment of kind {missing}: each of ground, wall and arch must appear")
    order = np.argsort(kind, kind="stable")
    starts = np.searchsorted(kind[order], np.arange(len(SURFACES)))
    return Profile(str(path), yz, a[order], b[order], kind[order], starts, order, nxt[order])
