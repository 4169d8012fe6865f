"""Clearances of a boom configuration: self, wall, ground and arch (docs/reference.md, section 2).

One function, :meth:`SafetyModel.clearances`, measures how far each safety
distance is kept (metres, negative when violated). The boolean checks used in
evaluation and the hinge penalties used in training are both derived from it, so
the two can never disagree: a check fails exactly where its penalty is positive.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rotations import safe_norm
from pipeline.geometry.tunnel import SURFACES, Horseshoe

SAFETY_KINDS = ("self", *SURFACES)
# The candidate points of the exact capsule-tunnel check (see :meth:`SafetyModel._fractions`).
EXACT_CANDIDATES = 6
MAX_POINTS_PER_CAPSULE = 256  # safety.points_per_capsule (conf/safety/paper.yaml): 16 times the paper's 16


def capsule_settings(points_per_capsule, exact_capsules, max_points: int | None = MAX_POINTS_PER_CAPSULE
                     ) -> tuple[int, bool]:
    """``safety.points_per_capsule`` (a whole number >= 2, at most ``max_points`` unless None) and
    ``safety.exact_capsules`` (a boolean), validated."""
    if isinstance(points_per_capsule, bool) or not isinstance(points_per_capsule, int):
        raise ConfigError(f"safety.points_per_capsule = {points_per_capsule!r}: expected an integer")
    if points_per_capsule < 2:
        raise ConfigError(f"safety.points_per_capsule = {points_per_capsule!r}: need at least 2")
    if max_points is not None and points_per_capsule > max_points:  # every check measures them all
        raise ConfigError(f"safety.points_per_capsule = {points_per_capsule!r}: at most {max_points} "
                          "(each is measured in every clearance check of every configuration)")
    if not isinstance(exact_capsules, bool):
        raise ConfigError(f"safety.exact_capsules = {exact_capsules!r}: expected true or false")
    return points_per_capsule, exact_capsules


def segment_distance(p1: torch.Tensor, q1: torch.Tensor, p2: torch.Tensor, q2: torch.Tensor, eps: float = 1e-12):
    """Exact shortest distance between segments p1-q1 and p2-q2, batched over ``(..., 3)``.

    Clamped closest points (Ericson, *Real-Time Collision Detection*, 5.1.9), written
    with ``torch.where`` so that it vectorises and its gradient stays finite for
    parallel, degenerate and touching segments.
    Returns ``(distance, s, t)`` with the closest points ``p1 + s (q1 - p1)`` and ``p2 + t (q2 - p2)``.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = (d1 * d1).sum(-1)
    e = (d2 * d2).sum(-1)
    f = (d2 * r).sum(-1)
    c = (d1 * r).sum(-1)
    b = (d1 * d2).sum(-1)
    denom = a * e - b * b
    one = torch.ones_like(a)
    a_ok, e_ok = a > eps, e > eps
    a_safe, e_safe = torch.where(a_ok, a, one), torch.where(e_ok, e, one)
    # Parallel segments (denom ~ 0, relative to the dtype's precision): any s works;
    # take s = 0 and let the clamps below fix t.
    nonpar = denom > 64 * torch.finfo(a.dtype).eps * a * e
    s = torch.where(nonpar, (b * f - c * e) / torch.where(nonpar, denom, one), torch.zeros_like(a)).clamp(0, 1)
    t = (b * s + f) / e_safe
    s = torch.where(t < 0, (-c / a_safe).clamp(0, 1), torch.where(t > 1, ((b - c) / a_safe).clamp(0, 1), s))
    t = t.clamp(0, 1)
    # Degenerate cases: a point against a segment, or two points.
    s = torch.where(a_ok & ~e_ok, (-c / a_safe).clamp(0, 1), s)
    t = torch.where(~e_ok, torch.zeros_like(t), t)
    t = torch.where(~a_ok & e_ok, (f / e_safe).clamp(0, 1), t)
    s = torch.where(~a_ok, torch.zeros_like(s), s)
    c1 = p1 + s.unsqueeze(-1) * d1
    c2 = p2 + t.unsqueeze(-1) * d2
    return safe_norm(c1 - c2), s, t


@dataclass(frozen=True)
class SafetyDistances:
    self: float = 0.1
    wall: float = 0.5
    ground: float = 0.1
    arch: float = 0.1

    @classmethod
    def from_config(cls, cfg: Mapping) -> SafetyDistances:
        unknown = sorted(set(cfg) - set(SAFETY_KINDS))
        if unknown:
            raise ConfigError(f"safety: unknown field(s) {unknown}; allowed: {list(SAFETY_KINDS)}")
        values = {}
        for key in SAFETY_KINDS:
            if key not in cfg:
                raise ConfigError(f"safety: missing required field '{key}'")
            v = cfg[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"safety.{key} = {v!r}: expected a number (metres)")
            if v < 0:
                raise ConfigError(f"safety.{key} = {v!r}: a safety distance cannot be below zero")
            values[key] = float(v)
        return cls(**values)


class SafetyModel:
    """Clearances of boom configurations in a tunnel, batched over configurations.

    Every capsule is checked at once: the bodies' end points come from one gather of the frames,
    their checked points form one ``(..., bodies, points, 3)`` tensor, and the three tunnel surfaces
    are measured in one call, so the cost does not grow with Python loops over bodies or kinds.

    ``points_per_capsule`` evenly spaced points are checked along each capsule (paper 000's way; the
    minimum can then lie between two of them), and with ``exact`` (the default) also the
    :data:`EXACT_CANDIDATES` points where a surface's distance can be smallest (:meth:`_fractions`):
    the minimum over the whole axis of a capsule inside the profile. Outside it the samples keep the
    penalty at least as deep as the sampled model's (a capsule outside fails either way)."""

    def __init__(self, boom: Boom, tunnel: Horseshoe, distances: SafetyDistances, points_per_capsule: int = 16,
                 exact: bool = True):
        # The cap is the config's (build.safety_settings); a reference model built in code, such as a
        # dense sampling that a test measures the exact check against, may be denser.
        points_per_capsule, exact = capsule_settings(points_per_capsule, exact, max_points=None)
        if not boom.bodies:
            raise ConfigError(f"boom '{boom.name}' defines no collision bodies; the safety model needs them")
        self.boom, self.tunnel, self.distances = boom, tunnel, distances
        self.points_per_capsule, self.exact = points_per_capsule, exact
        self.n_points = points_per_capsule + (EXACT_CANDIDATES if exact else 0)  # checked points per capsule
        bodies = list(boom.bodies.values())
        self._names = [b.name for b in bodies]
        self._end_frames = [spec.frame for b in bodies for spec in (b.start, b.end)]
        self._end_along = [spec.along_z for b in bodies for spec in (b.start, b.end)]
        self._radius = [b.radius for b in bodies]
        self._skip = [b.tunnel_skip_end for b in bodies]
        self._pairs = [(self._names.index(a), self._names.index(b)) for a, b in boom.self_pairs]
        self._consts: dict = {}

    def with_distances(self, distances: SafetyDistances) -> SafetyModel:
        """The same boom and tunnel with other safety distances (the training penalties')."""
        return SafetyModel(self.boom, self.tunnel, distances, self.points_per_capsule, self.exact)

    def _c(self, dtype, device) -> dict[str, torch.Tensor]:
        key = (dtype, device)
        if key not in self._consts:
            t = lambda x: torch.tensor(x, dtype=dtype, device=device)  # noqa: E731
            self._consts[key] = {
                "frames": torch.tensor(self._end_frames, device=device), "along": t(self._end_along)[:, None],
                "radius": t(self._radius), "skip": t(self._skip),
                "surface": t([getattr(self.distances, k) for k in SURFACES]),
                "t": torch.linspace(0.0, 1.0, self.points_per_capsule, dtype=dtype, device=device),
            }
        return self._consts[key]

    def body_ends(self, frames: torch.Tensor) -> torch.Tensor:
        """Start and end of every capsule's axis: ``(..., bodies, 2, 3)``."""
        c = self._c(frames.dtype, frames.device)
        F = frames[..., c["frames"], :3, :]
        return (F[..., 3] + c["along"] * F[..., 2]).reshape(*frames.shape[:-3], len(self._names), 2, 3)

    def _fractions(self, start: torch.Tensor, axis: torch.Tensor) -> torch.Tensor:
        """Where along the checked axis ``start + u axis`` (``u`` in [0, 1]) the tunnel distances can be
        smallest: ``(..., bodies, EXACT_CANDIDATES)``.

        Inside the profile each surface's distance, as a function of ``u``, is piecewise (cut where
        ``z`` crosses the wall height and ``y`` crosses 0) linear (ground; wall below the wall height),
        concave (arch above the springing line: the radius less a convex norm) or the distance to a
        corner ``(+-width/2, wall_height)`` (wall above, arch below: convex). The smallest value is at
        an end of a piece or where a convex piece is lowest, the corner's projection on the axis. A
        capsule that leaves the profile has an end beyond some surface, so its clearance is negative
        there and it fails either way. The fractions carry no gradient: at a minimum the derivative
        along the axis is zero or the point is an end (the envelope theorem), as for a sample point."""
        with torch.no_grad():
            r, h = self.tunnel.half_width, self.tunnel.wall_height
            y0, z0, dy, dz = start[..., 1], start[..., 2], axis[..., 1], axis[..., 2]

            def crossing(v0, dv, level):  # where v0 + u dv = level inside (0, 1), else the start
                ok = dv.abs() > 1e-15
                u = (level - v0) / torch.where(ok, dv, torch.ones_like(dv))
                return torch.where(ok & (u > 0) & (u < 1), u, torch.zeros_like(u))

            dd = dy * dy + dz * dz
            dd_ok = dd > 1e-24
            dd_safe = torch.where(dd_ok, dd, torch.ones_like(dd))

            def projection(cy):  # the axis point nearest the corner (cy, h)
                u = ((cy - y0) * dy + (h - z0) * dz) / dd_safe
                return torch.where(dd_ok, u.clamp(0.0, 1.0), torch.zeros_like(u))

            return torch.stack([torch.zeros_like(y0), torch.ones_like(y0), crossing(z0, dz, h),
                                crossing(y0, dy, 0.0), projection(r), projection(-r)], dim=-1)

    def _tunnel(self, ends: torch.Tensor, radius: torch.Tensor, skip: torch.Tensor):
        """Clearance to each surface ``(..., 3, bodies * points)`` of every checked point and where each
        lies between its body's ends ``(..., 3, bodies * points)``. A body's last ``skip`` metres are not
        checked (the feed's front works at the face). A horseshoe is checked at points along each axis
        (the samples, then the exact candidates); a profile measures each whole axis at once
        (:meth:`Profile.capsule_distances`), one "point" per body and surface."""
        c = self._c(ends.dtype, ends.device)
        start, axis = ends[..., 0, :], ends[..., 1, :] - ends[..., 0, :]
        keep = torch.where(skip > 0, (1.0 - skip / safe_norm(axis).clamp_min(1e-12)).clamp_min(0.0), 1.0)
        if self.tunnel.kind == "profile":
            dist, frac = self.tunnel.capsule_distances(start, keep.unsqueeze(-1) * axis)  # (..., bodies, 3)
            clear = dist - radius[:, None] - c["surface"]
            return clear.transpose(-1, -2), (frac * keep.unsqueeze(-1)).transpose(-1, -2)
        u = c["t"].expand(*start.shape[:-1], -1)
        if self.exact:
            u = torch.cat([u, self._fractions(start, keep.unsqueeze(-1) * axis)], dim=-1)
        frac = u * keep.unsqueeze(-1)
        pts = start.unsqueeze(-2) + frac.unsqueeze(-1) * axis.unsqueeze(-2)
        dist = self.tunnel.surface_distances(pts[..., 1], pts[..., 2])
        clear = torch.stack([dist[k] for k in SURFACES], dim=-3) - radius[:, None] - c["surface"][:, None, None]
        clear = clear.flatten(-2)
        return clear, frac.flatten(-2).unsqueeze(-2).expand_as(clear)

    @property
    def points_per_body(self) -> int:
        """Checked points per capsule in :meth:`_tunnel`'s layout (a profile measures each axis whole)."""
        return 1 if self.tunnel.kind == "profile" else self.n_points

    def _self(self, ends: torch.Tensor):
        """Self clearance (min over the listed pairs), and the minimising pair's closest-point
        parameters ``s, t`` and body indices (for the gradient)."""
        best = None
        for a, b in self._pairs:  # a loop over body pairs (jumbo8: one), batched over configurations
            (a0, a1), (b0, b1) = ends[..., a, :, :].unbind(-2), ends[..., b, :, :].unbind(-2)
            dist, s, t = segment_distance(a0, a1, b0, b1)
            c = dist - self._radius[a] - self._radius[b] - self.distances.self
            if best is None:
                best = (c, s, t, torch.full_like(s, a, dtype=torch.long), torch.full_like(s, b, dtype=torch.long))
            else:
                take = c < best[0]
                new = (c, s, t, torch.full_like(best[3], a), torch.full_like(best[4], b))
                best = tuple(torch.where(take, n, o) for n, o in zip(new, best, strict=True))
        return best

    def clearances(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per configuration, the margin (m) by which each safety distance is kept.

        ``{"self", "wall", "ground", "arch"}`` -> tensor ``q.shape[:-1]``; negative
        means violated. Self: clamped segment-segment distance of every listed pair
        less both radii and ``d_self``. Tunnel: every sample point of every capsule,
        inflated by its radius, against each surface.
        """
        return self.clearances_from_frames(self.boom.frames(q))

    def clearances_from_frames(self, frames: torch.Tensor) -> dict[str, torch.Tensor]:
        c = self._c(frames.dtype, frames.device)
        ends = self.body_ends(frames)
        tunnel = self._tunnel(ends, c["radius"], c["skip"])[0].amin(dim=-1)
        pair = self._self(ends)
        selfc = pair[0] if pair is not None else torch.full(  # no self pairs: self collision cannot happen
            frames.shape[:-3], math.inf, dtype=frames.dtype, device=frames.device)
        return {"self": selfc, **{k: tunnel[..., i] for i, k in enumerate(SURFACES)}}

    def clearances_with_jacobians(self, frames: torch.Tensor) -> tuple[dict[str, torch.Tensor], dict]:
        """The clearances of :meth:`clearances_from_frames` and their gradients ``(..., n_joints)``
        with respect to the joints, from one forward pass (no autograd: solvers call it every step).

        A clearance is a minimum over sample points (tunnel) or the closest points of two segments
        (self), so its gradient is the gradient at the minimising point: the surface's unit normal
        (or the unit vector between the closest points) times that point's geometric Jacobian. The
        feed's checked length is fixed (its length is), so the truncation adds no term."""
        boom, c = self.boom, self._c(frames.dtype, frames.device)
        batch, nb, P = frames.shape[:-3], len(self._names), self.points_per_body
        ends = self.body_ends(frames)
        clear, frac = self._tunnel(ends, c["radius"], c["skip"])
        values, i = clear.min(dim=-1)  # (..., 3 surfaces)
        jac = boom.points_jacobian(frames, ends.flatten(-3, -2), c["frames"]).reshape(*batch, nb, 2, 3, -1)
        body = (i // P)[..., None, None, None].expand(*i.shape, 2, 3, jac.shape[-1])
        j_ends = torch.gather(jac, -4, body)  # (..., 3 surfaces, 2, 3, n)
        a = torch.gather(frac, -1, i.unsqueeze(-1))  # (..., 3, 1)
        j_point = (1 - a[..., None]) * j_ends[..., 0, :, :] + a[..., None] * j_ends[..., 1, :, :]
        e = torch.gather(ends, -3, (i // P)[..., None, None].expand(*i.shape, 2, 3))  # (..., 3, 2, 3)
        p = e[..., 0, :] + a * (e[..., 1, :] - e[..., 0, :])
        normals = self.tunnel.surface_gradients(p[..., 1], p[..., 2])
        gy = torch.stack([normals[k][0][..., s] for s, k in enumerate(SURFACES)], dim=-1)
        gz = torch.stack([normals[k][1][..., s] for s, k in enumerate(SURFACES)], dim=-1)
        tunnel_grad = gy.unsqueeze(-1) * j_point[..., 1, :] + gz.unsqueeze(-1) * j_point[..., 2, :]
        out = {k: values[..., s] for s, k in enumerate(SURFACES)}
        grads = {k: tunnel_grad[..., s, :] for s, k in enumerate(SURFACES)}
        pair = self._self(ends)
        if pair is None:  # no self pairs: self collision cannot happen
            out["self"] = torch.full(batch, math.inf, dtype=frames.dtype, device=frames.device)
            grads["self"] = torch.zeros(*batch, boom.n_joints, dtype=frames.dtype, device=frames.device)
        else:
            sc, s, t, ia, ib = pair
            pick = lambda idx: torch.gather(  # noqa: E731  the two ends of body idx, and their Jacobians
                ends, -3, idx[..., None, None, None].expand(*idx.shape, 1, 2, 3)).squeeze(-3)
            pick_j = lambda idx: torch.gather(  # noqa: E731
                jac, -4, idx[..., None, None, None, None].expand(*idx.shape, 1, 2, 3, jac.shape[-1])).squeeze(-4)
            ea, eb, ja, jb = pick(ia), pick(ib), pick_j(ia), pick_j(ib)
            s_, t_ = s[..., None], t[..., None]
            on_a = ea[..., 0, :] + s_ * (ea[..., 1, :] - ea[..., 0, :])
            gap = on_a - (eb[..., 0, :] + t_ * (eb[..., 1, :] - eb[..., 0, :]))
            u = gap / safe_norm(gap).clamp_min(1e-12)[..., None]
            s_, t_ = s_[..., None], t_[..., None]
            j_rel = ((1 - s_) * ja[..., 0, :, :] + s_ * ja[..., 1, :, :]
                     - (1 - t_) * jb[..., 0, :, :] - t_ * jb[..., 1, :, :])
            out["self"], grads["self"] = sc, (u.unsqueeze(-1) * j_rel).sum(-2)
        return {k: out[k] for k in SAFETY_KINDS}, {k: grads[k] for k in SAFETY_KINDS}

    def tool_body_clearances(self, p: torch.Tensor, z: torch.Tensor) -> dict[str, torch.Tensor]:
        """Tunnel clearances of the bodies fixed to the tool frame, from a hole pose alone.

        Used to reject holes that no joint solution can drill: if the feed beam at
        the hole already violates a tunnel safety distance, so does every solution.
        """
        tool = self.boom.tool_index
        bodies = [b for b in self.boom.bodies.values() if b.start.frame == tool and b.end.frame == tool]
        if not bodies:
            raise ConfigError(f"boom '{self.boom.name}' has no body fixed to the tool frame")
        t = lambda x: torch.tensor(x, dtype=p.dtype, device=p.device)  # noqa: E731
        along = t([[b.start.along_z, b.end.along_z] for b in bodies])  # (bodies, 2)
        ends = p[..., None, None, :] + along[..., None] * z[..., None, None, :]
        clear = self._tunnel(ends, t([b.radius for b in bodies]), t([b.tunnel_skip_end for b in bodies]))[0]
        worst = clear.amin(dim=-1)
        return {k: worst[..., i] for i, k in enumerate(SURFACES)}

    # Both views below derive from the same clearances.
    @staticmethod
    def violations(clearances: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {k: c < 0 for k, c in clearances.items()}

    @staticmethod
    def penalties(clearances: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Hinge of each clearance (paper 000 eqs. 14-15): zero exactly where the check passes."""
        return {k: torch.relu(-c) for k, c in clearances.items()}

