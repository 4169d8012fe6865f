"""Distances, batched over any leading shape: clamped segment-segment distance (any dimension) and the
horseshoe tunnel's signed distances (docs/reference.md, section 2), exact over a whole segment. A tunnel of any
cross-section (``tunnel=profile``) is :mod:`.profile`'s; :class:`Horseshoe` and its :class:`~.profile.Profile`
answer the sweep alike (``clearances(p0, p1)``, ``describe()``).

Tunnel convention (the YAML's and the reference's, in the rig frame's (y, z) plane): floor z = 0, walls
|y| = width/2 for z in [0, wall_height], arch the upper semicircle of radius width/2 centred at
(0, wall_height). Each surface's distance is the exact distance to that piece of the outline,
positive inside the profile and negative beyond it; a body's clearance to a surface is that distance
minus its radius minus the surface's safety distance, and it passes when it is >= 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SURFACES = ("wall", "ground", "arch")
_TINY = 1e-18


def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


def segment_distance(p1, q1, p2, q2) -> np.ndarray:
    """Shortest distance between segments [p1, q1] and [p2, q2] (clamped: end points included).

    Closest points of the two lines, clamped to the segments in turn (the standard construction:
    s from the lines, t from s, then s again from the clamped t); a segment of zero length is a point.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    a_ok, e_ok = a > _TINY, e > _TINY
    a_s, e_s = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    # parallel (or a point): any s is a closest candidate, take s = 0 and let t decide
    s = np.where(denom > 1e-12 * a_s * e_s, np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_s
    s = np.where(t < 0.0, np.clip(-c / a_s, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a_s, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    # second segment a point: t = 0, s from the point's projection
    s = np.where(e_ok, s, np.clip(-c / a_s, 0.0, 1.0))
    t = np.where(e_ok, t, 0.0)
    s = np.where(a_ok, s, 0.0)
    t = np.where(a_ok, t, np.where(e_ok, np.clip(f / e_s, 0.0, 1.0), 0.0))
    gap = (p1 + s[..., None] * d1) - (p2 + t[..., None] * d2)
    return np.sqrt(_dot(gap, gap))


def point_distances(y, z, half_width: float, wall_height: float) -> dict[str, np.ndarray]:
    """Signed distance of points (y, z) to the wall, the ground and the arch (convention above).

    Wall: the nearest of the two vertical segments; above ``wall_height`` that is the segment's top
    end. Arch: below its springing line the nearest arch point is one of its two ends.
    """
    r, h = half_width, wall_height
    inward = r - np.abs(y)
    sign = np.where(inward < 0, -1.0, 1.0)
    above = z > h
    wall = np.where(above, sign * np.hypot(inward, z - h), inward)
    arch = np.where(above, r - np.hypot(y, z - h), sign * np.hypot(inward, h - z))
    return {"wall": wall, "ground": z, "arch": arch}


def segment_tunnel(p0, p1, half_width: float, wall_height: float) -> np.ndarray:
    """``(..., 3)``: the smallest signed distance of any point of segment [p0, p1] (rig frame, x y z)
    to the wall, the ground and the arch, in :data:`SURFACES` order.

    Exact for a segment inside the profile: along the segment each distance is, piece by piece
    (pieces cut where z crosses ``wall_height`` and y crosses 0), linear, concave (arch above the
    springing line: radius minus a convex norm) or the distance to a corner point (convex): its
    minimum lies at a piece end or at the projection of a corner (+-width/2, wall_height), so the
    minimum over those six candidate points is the minimum over the segment. A segment reaching out
    of the profile has an end beyond some surface, whose distance there is negative.
    """
    r, h = half_width, wall_height
    a, b = p0[..., 1:], p1[..., 1:]  # (y, z): the profile does not depend on x
    d = b - a
    dd = _dot(d, d)
    dds = np.where(dd > _TINY, dd, 1.0)

    def crossing(k, level):
        den = d[..., k]
        u = (level - a[..., k]) / np.where(np.abs(den) > 1e-15, den, 1.0)
        return np.where((np.abs(den) > 1e-15) & (u > 0) & (u < 1), u, 0.0)

    def project(corner):
        return np.where(dd > _TINY, np.clip(_dot(corner - a, d) / dds, 0.0, 1.0), 0.0)

    us = np.stack([np.zeros(dd.shape), np.ones(dd.shape), crossing(1, h), crossing(0, 0.0),
                   project(np.array([r, h])), project(np.array([-r, h]))], -1)
    pts = a[..., None, :] + us[..., None] * d[..., None, :]
    dist = point_distances(pts[..., 0], pts[..., 1], r, h)
    return np.stack([dist[k].min(-1) for k in SURFACES], -1)


@dataclass
class Horseshoe:
    """The horseshoe drift of ``tunnel.kind: horseshoe`` (a tunnel node with ``width`` and no kind is one)."""

    half_width: float
    wall_height: float

    def clearances(self, p0, p1) -> np.ndarray:
        """``(..., 3)``: :func:`segment_tunnel` of the axes [p0, p1], :data:`SURFACES` order."""
        return segment_tunnel(p0, p1, self.half_width, self.wall_height)

    def describe(self) -> dict:
        return {"kind": "horseshoe", "width": 2 * self.half_width, "wall_height": self.wall_height}
