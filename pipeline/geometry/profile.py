"""A drift of any cross-section: a closed polyline whose segments are ground, wall or arch.

The tunnel is the polyline's polygon extruded along x (a prism), in the rig frame's (y, z) plane. A
profile file is a CSV ``y, z, surface``: the vertices in order around the profile (either way round);
the segment from a vertex to the next (the last to the first) is a surface of the vertex's kind.

Distances (docs/plans_to_rig.md, "Tunnel profiles"), the same rule as the horseshoe's where both apply:

- **A point's distance to a kind** is its distance to the nearest segment of that kind, positive,
  except for a point outside the polygon, whose distance to the kind(s) of its nearest boundary segment
  is negative (the depth it has left the drift by; beyond a corner both kinds meeting there, ties within
  :data:`TIE`). So a check fails exactly where a point has left the
  profile or comes nearer than a safety distance to a surface, and a penalty's gradient points back in.
- **A capsule's distance to a kind** (its axis, a segment ``a-b`` seen in the (y, z) plane): the least
  2-D distance between ``a-b`` and the kind's segments (0 where they cross), and, for an end of the axis
  outside the polygon, that end's negative depth for the kind nearest to it. Inside the profile this is
  the exact distance from the whole axis to the kind, found from the segment pairs directly (no
  sampling along the axis): the minimum of a distance between two segments lies at one of their ends or
  where they cross. An axis that leaves the profile crosses a segment (distance 0) or has an end outside
  (negative), so its clearance fails whatever the radius.

Batched over any leading shape and differentiable (the training penalties); a loop runs over nothing but
the leading dimensions' broadcast. The compiled kernels follow the same rule
(:mod:`pipeline.geometry.compiled_kinematics`), and the independent round checker has its own code.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import torch

from pipeline.core.csv_input import read_text_csv
from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.collision import segment_distance
from pipeline.geometry.rotations import safe_norm
from pipeline.geometry.tunnel import SURFACES

MIN_SEGMENT = 1e-6  # m: a shorter segment has no direction
TIE = 1e-9  # m: kinds this close to a point's nearest boundary distance are all nearest (a corner's two kinds)
MAX_VERTICES = 2000
_KIND = {k: i for i, k in enumerate(SURFACES)}


def read_profile_csv(path: str | Path, max_vertices: int = MAX_VERTICES) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(n, 2)`` and the kind index (into :data:`SURFACES`) of the segment each starts, from a
    profile CSV; every fault names the file and the row (the header is row 1)."""
    import pandas as pd

    df = read_text_csv(path, "tunnel profile (tunnel.file)", ["y", "z", "surface"], lower=True)
    if not 3 <= len(df) <= max_vertices:
        raise InputError(f"{path}: {len(df)} vertices; a tunnel profile needs 3 to tunnel.max_vertices = "
                         f"{max_vertices}")
    yz = np.stack([pd.to_numeric(df[c].str.strip(), errors="coerce").to_numpy(float) for c in ("y", "z")], -1)
    bad = ~np.isfinite(yz).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: row {i + 2}: y = {df['y'].iloc[i]!r}, z = {df['z'].iloc[i]!r}: expected two "
                         "finite numbers (m)")
    names = df["surface"].str.strip().str.lower()
    unknown = ~names.isin(SURFACES)
    if unknown.any():
        i = int(np.flatnonzero(unknown.to_numpy())[0])
        raise InputError(f"{path}: row {i + 2}: surface {df['surface'].iloc[i]!r}: expected one of {list(SURFACES)}")
    kinds = names.map(_KIND).to_numpy(np.int64)
    check_outline(yz, kinds, str(path))
    return yz, kinds


def check_outline(yz: np.ndarray, kinds: np.ndarray, source: str) -> None:
    """Refuse an outline that is no drift: a segment too short to have a direction, a kind that no segment
    has, or a polyline that crosses itself (rows are named as in the file: the header is row 1)."""
    n = len(yz)
    nxt = np.roll(yz, -1, axis=0)
    length = np.linalg.norm(nxt - yz, axis=1)
    if (length < MIN_SEGMENT).any():
        i = int(np.argmin(length))
        raise InputError(f"{source}: rows {i + 2} and {(i + 1) % n + 2}: a segment of {length[i]:.3g} m (a repeated "
                         "vertex); a tunnel profile's segments are at least 1e-6 m long")
    absent = [k for i, k in enumerate(SURFACES) if not (kinds == i).any()]
    if absent:
        raise InputError(f"{source}: no segment of kind {absent}; a tunnel profile has ground, wall and arch "
                         "segments (each kind's safety distance needs a surface to keep it from)")
    # Two segments that are not neighbours must not meet (a touching end included): every pair at once.
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the last segment's neighbour is the first
    i, j = i[keep], j[keep]
    p0, p1 = torch.as_tensor(yz), torch.as_tensor(nxt)
    gap = segment_distance(p0[i], p1[i], p0[j], p1[j])[0].numpy()
    if (gap < MIN_SEGMENT).any():
        k = int(np.argmin(gap))
        raise InputError(f"{source}: the segment from row {int(i[k]) + 2} and the one from row {int(j[k]) + 2} meet; "
                         "a tunnel profile is a simple closed polyline")


class Profile:
    """A tunnel of any cross-section (module docstring), with the horseshoe's interface."""

    kind = "profile"

    def __init__(self, yz: np.ndarray, kinds: np.ndarray, source: str = "profile"):
        yz = np.array(yz, dtype=np.float64)  # copies: the profile owns its arrays
        kinds = np.array(kinds, dtype=np.int64)
        if yz.ndim != 2 or yz.shape[1] != 2 or kinds.shape != (len(yz),) or len(yz) < 3:
            raise ConfigError(f"{source}: a profile needs (n, 2) vertices and n kinds, n >= 3")
        check_outline(yz, kinds, source)
        self.source, self.yz, self.kinds = source, yz, kinds
        nxt = np.roll(yz, -1, axis=0)
        area = 0.5 * float((yz[:, 0] * nxt[:, 1] - nxt[:, 0] * yz[:, 1]).sum())
        d = nxt - yz
        self.inward_sign = 1.0 if area > 0 else -1.0
        inward = np.stack([-d[:, 1], d[:, 0]], -1) * self.inward_sign  # left of a counter-clockwise edge
        self.inward = inward / np.linalg.norm(inward, axis=1, keepdims=True)
        self.segments = np.concatenate([yz, nxt], axis=1)  # (m, 4): y0, z0, y1, z1
        self.area = abs(area)
        # what the profile is, whatever its file is called: in a training's digest and its MLflow params
        self.md5 = hashlib.md5(yz.tobytes() + kinds.tobytes()).hexdigest()
        self._consts: dict = {}

    @classmethod
    def from_file(cls, path: str | Path, max_vertices: int = MAX_VERTICES) -> Profile:
        yz, kinds = read_profile_csv(path, max_vertices)
        return cls(yz, kinds, str(path))

    # -- identity and size -------------------------------------------------------------------------
    def _key(self):
        return self.yz.tobytes(), self.kinds.tobytes()

    def __eq__(self, other) -> bool:
        return isinstance(other, Profile) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        return f"Profile({self.source!r}, {len(self.yz)} vertices)"

    @property
    def y_range(self) -> tuple[float, float]:
        return float(self.yz[:, 0].min()), float(self.yz[:, 0].max())

    @property
    def z_range(self) -> tuple[float, float]:
        return float(self.yz[:, 1].min()), float(self.yz[:, 1].max())

    @property
    def width(self) -> float:
        lo, hi = self.y_range
        return hi - lo

    @property
    def crown(self) -> float:
        return self.z_range[1]

    def describe(self) -> str:
        return f"profile {Path(self.source).name} ({self.width:g} x {self.z_range[1] - self.z_range[0]:g} m, " \
               f"{len(self.yz)} vertices)"

    def profile_polyline(self) -> tuple[list[float], list[float]]:
        """Outline (y, z) for plots, closed."""
        ys, zs = self.yz[:, 0].tolist(), self.yz[:, 1].tolist()
        return [*ys, ys[0]], [*zs, zs[0]]

    def outline_array(self) -> np.ndarray:
        """``(m, 7)``: each segment's y0, z0, y1, z1, kind index and inward unit normal (ny, nz), for the
        compiled kernels."""
        return np.ascontiguousarray(np.concatenate([self.segments, self.kinds[:, None].astype(np.float64),
                                                    self.inward], axis=1))

    def _c(self, dtype, device) -> dict[str, torch.Tensor]:
        key = (dtype, device)
        if key not in self._consts:
            t = lambda x: torch.as_tensor(x, dtype=dtype, device=device)  # noqa: E731
            mask = torch.stack([torch.as_tensor(self.kinds == i, device=device) for i in range(len(SURFACES))])
            self._consts[key] = {"p0": t(self.segments[:, :2]), "p1": t(self.segments[:, 2:]),
                                 "inward": t(self.inward), "mask": mask,
                                 "kinds": torch.as_tensor(self.kinds, device=device)}
        return self._consts[key]

    # -- points ------------------------------------------------------------------------------------
    def _inside(self, yz: torch.Tensor, c: dict) -> torch.Tensor:
        """Even-odd rule over every segment at once; ``yz (..., 2)`` -> ``(...,)`` (boundary points are
        decided by the distances that use this: they are 0 there either way)."""
        y, z = yz[..., None, 0], yz[..., None, 1]
        y0, z0, y1, z1 = c["p0"][:, 0], c["p0"][:, 1], c["p1"][:, 0], c["p1"][:, 1]
        straddle = (z0 > z) != (z1 > z)
        dz = torch.where(straddle, z1 - z0, torch.ones_like(z1 - z0))
        left = y < y0 + (z - z0) * (y1 - y0) / dz
        return ((straddle & left).sum(-1) % 2) == 1

    def _point_segments(self, yz: torch.Tensor, c: dict):
        """Distance ``(..., m)`` from points ``(..., 2)`` to every segment, and the nearest point of each."""
        p0, d = c["p0"], c["p1"] - c["p0"]
        rel = yz[..., None, :] - p0
        s = ((rel * d).sum(-1) / (d * d).sum(-1)).clamp(0.0, 1.0)
        near = p0 + s[..., None] * d
        return safe_norm(yz[..., None, :] - near), near

    def _per_kind(self, dist: torch.Tensor, c: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """Least value per kind ``(..., 3)`` of a per-segment tensor ``(..., m)``, and which segment."""
        big = torch.full((), math.inf, dtype=dist.dtype, device=dist.device)
        return torch.where(c["mask"], dist[..., None, :], big).min(dim=-1)

    def _signed(self, yz: torch.Tensor, c: dict):
        """Per kind, the point's signed distance (module docstring) ``(..., 3)``, the nearest point of that
        kind ``(..., 3, 2)``, the sign ``(..., 3)`` and the nearest segment's index ``(..., 3)``."""
        dist, near = self._point_segments(yz, c)
        per, seg = self._per_kind(dist, c)
        # every kind at the boundary's distance: beyond a corner both kinds meeting there are as near
        own = per <= per.min(dim=-1, keepdim=True).values + TIE
        outside = ~self._inside(yz, c)
        sign = torch.where(outside[..., None] & own, -1.0, 1.0).to(yz.dtype)
        point = torch.gather(near, -2, seg[..., None].expand(*seg.shape, 2))
        return sign * per, point, sign, seg

    def surface_distances(self, y: torch.Tensor, z: torch.Tensor) -> dict[str, torch.Tensor]:
        """Signed distance of points (y, z) to each kind (module docstring)."""
        c = self._c(y.dtype, y.device)
        values = self._signed(torch.stack(torch.broadcast_tensors(y, z), -1), c)[0]
        return {k: values[..., i] for i, k in enumerate(SURFACES)}

    def surface_gradients(self, y: torch.Tensor, z: torch.Tensor) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """``(d/dy, d/dz)`` of each distance of :meth:`surface_distances`: the unit vector from the
        nearest point of the kind, signed like the distance; on a segment (distance 0), its inward normal."""
        c = self._c(y.dtype, y.device)
        yz = torch.stack(torch.broadcast_tensors(y, z), -1)
        _, point, sign, seg = self._signed(yz, c)
        gap = yz[..., None, :] - point
        norm = safe_norm(gap)
        unit = torch.where((norm > 1e-12)[..., None], gap / norm.clamp_min(1e-12)[..., None], c["inward"][seg])
        g = sign[..., None] * unit
        return {k: (g[..., i, 0], g[..., i, 1]) for i, k in enumerate(SURFACES)}

    def contains(self, y: torch.Tensor, z: torch.Tensor, inset: float = 0.0) -> torch.Tensor:
        """Boolean: (y, z) lies inside the profile shrunk by ``inset``."""
        d = self.surface_distances(y, z)
        return (d["wall"] >= inset) & (d["ground"] >= inset) & (d["arch"] >= inset)

    def sample_yz(self, m: int, inset: float, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """``m`` candidate points uniform in the profile's bounding box less ``inset`` (the caller keeps
        those :meth:`contains` accepts)."""
        (y0, y1), (z0, z1) = self.y_range, self.z_range
        if y1 - y0 <= 2 * inset or z1 - z0 <= 2 * inset:
            raise ConfigError(f"holes.inset = {inset!r} leaves no area inside the tunnel profile {self.source}")
        y = y0 + inset + torch.rand(m, generator=gen, dtype=torch.float64) * (y1 - y0 - 2 * inset)
        z = z0 + inset + torch.rand(m, generator=gen, dtype=torch.float64) * (z1 - z0 - 2 * inset)
        return y, z

    # -- the outline as paths (the face designer's perimeter and floor) -------------------------------
    def paths(self) -> tuple[BoundaryPath, BoundaryPath]:
        """The floor (the longest run of ground segments, left to right) and the rest of the outline (from
        the floor's left end up, over the roof, down to its right end), as :class:`BoundaryPath`."""
        yz, kinds = self.yz, self.kinds
        if self.inward_sign < 0:  # walk counter-clockwise: the floor then runs left to right
            yz, kinds = yz[::-1].copy(), np.roll(kinds[::-1], -1).copy()
        ground = kinds == _KIND["ground"]
        n = len(kinds)
        runs = [(i, next(k for k in range(1, n + 1) if not ground[(i + k) % n]))  # (first segment, length)
                for i in range(n) if ground[i] and not ground[i - 1]] or [(0, n)]
        first, count = max(runs, key=lambda r: r[1])
        order = np.roll(np.arange(n), -first)
        pts = yz[order]
        floor = pts[: count + 1]
        rest = np.concatenate([pts[count:], pts[:1]])[::-1]  # from the floor's left end round to its right end
        return BoundaryPath(floor, 1), BoundaryPath(rest, -1)

    # -- capsules ----------------------------------------------------------------------------------
    def capsule_distances(self, start: torch.Tensor, axis: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per capsule axis ``start + u axis`` (``u`` in [0, 1], ``(..., 3)``, x ignored), its distance to
        each kind ``(..., 3)`` (module docstring) and where along the axis it is reached ``(..., 3)``."""
        c = self._c(start.dtype, start.device)
        a, b = start[..., 1:], start[..., 1:] + axis[..., 1:]
        dist, s, _ = segment_distance(a[..., None, :], b[..., None, :], c["p0"], c["p1"])  # (..., m)
        values, seg = self._per_kind(dist, c)
        frac = torch.gather(s, -1, seg)
        for end, u in ((a, 0.0), (b, 1.0)):  # an end outside: its depth, for the kind nearest to it
            signed = self._signed(end, c)[0]
            deeper = signed < values
            values = torch.where(deeper, signed, values)
            frac = torch.where(deeper, torch.full_like(frac, u), frac)
        return values, frac


class BoundaryPath:
    """A run of the outline as a path parametrised by arc length: points and outward unit normals at any
    lengths, for the face designer's contour holes and lifters. ``vertices (k + 1, 2)`` in walking order;
    ``side`` is +1 when the drift's inside lies left of the walk, -1 when it lies right."""

    def __init__(self, vertices: np.ndarray, side: int):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        step = np.diff(self.vertices, axis=0)
        self.seg_length = np.linalg.norm(step, axis=1)
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_length)])
        left = np.stack([-step[:, 1], step[:, 0]], -1) / self.seg_length[:, None]
        self.outward = -side * left  # away from the drift

    @property
    def length(self) -> float:
        return float(self.cum[-1])

    def at(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Points ``(n, 2)`` and outward normals ``(n, 2)`` at arc lengths ``s (n,)`` (clamped to the path)."""
        s_np = np.clip(s.detach().cpu().numpy().astype(np.float64), 0.0, self.length)
        i = np.clip(np.searchsorted(self.cum, s_np, side="right") - 1, 0, len(self.seg_length) - 1)
        u = (s_np - self.cum[i]) / self.seg_length[i]
        pts = self.vertices[i] + u[:, None] * (self.vertices[i + 1] - self.vertices[i])
        return torch.as_tensor(pts, dtype=torch.float64), torch.as_tensor(self.outward[i].copy(), dtype=torch.float64)

    def first_at_height(self, rise: float, from_end: bool = False) -> float:
        """The least arc length (from the start, or from the end when ``from_end``) where the path has risen
        ``rise`` above its own end point; the path's length when it never does."""
        v = self.vertices[::-1] if from_end else self.vertices
        cum = self.length - self.cum[::-1] if from_end else self.cum
        target = v[0, 1] + rise
        for k in range(len(v) - 1):
            z0, z1 = v[k, 1], v[k + 1, 1]
            if z1 >= target > z0 or z0 >= target:
                u = 0.0 if z0 >= target else (target - z0) / (z1 - z0)
                return float(cum[k] + u * (cum[k + 1] - cum[k]))
        return self.length
