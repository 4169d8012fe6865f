"""Clearances of a boom configuration: self, wall, ground and arch (spec section 2).

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
from pipeline.geometry.kinematics import Boom, Capsule
from pipeline.geometry.rotations import safe_norm
from pipeline.geometry.tunnel import SURFACES, Horseshoe

SAFETY_KINDS = ("self", *SURFACES)


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
    """Clearances of boom configurations in a tunnel, batched over configurations."""

    def __init__(self, boom: Boom, tunnel: Horseshoe, distances: SafetyDistances, points_per_capsule: int = 16):
        if points_per_capsule < 2:
            raise ConfigError(f"safety.points_per_capsule = {points_per_capsule!r}: need at least 2")
        if not boom.bodies:
            raise ConfigError(f"boom '{boom.name}' defines no collision bodies; the safety model needs them")
        self.boom, self.tunnel, self.distances = boom, tunnel, distances
        self.n_points = int(points_per_capsule)

    def with_distances(self, distances: SafetyDistances) -> SafetyModel:
        """The same boom and tunnel with other safety distances (the training penalties')."""
        return SafetyModel(self.boom, self.tunnel, distances, self.n_points)

    def _tunnel_points(self, body: Capsule, start: torch.Tensor, end: torch.Tensor):
        """``n_points`` points ``(..., P, 3)`` along the part of a capsule's axis checked against the
        tunnel, and where each lies as a fraction ``(..., P)`` of the way from ``start`` to ``end``."""
        t = torch.linspace(0.0, 1.0, self.n_points, dtype=start.dtype, device=start.device)
        axis = end - start
        if body.tunnel_skip_end:
            length = safe_norm(axis).unsqueeze(-1)
            t = t * (1.0 - body.tunnel_skip_end / length.clamp_min(1e-12)).clamp_min(0.0)
        else:
            t = t.expand(*start.shape[:-1], -1)
        return start.unsqueeze(-2) + t.unsqueeze(-1) * axis.unsqueeze(-2), t

    def _tunnel_clearances(self, bodies) -> dict[str, torch.Tensor]:
        """Min clearance to each tunnel surface over every given body's sample points."""
        worst: dict[str, torch.Tensor] = {}
        for body, start, end in bodies:
            pts, _ = self._tunnel_points(body, start, end)
            dist = self.tunnel.surface_distances(pts[..., 1], pts[..., 2])
            for kind in SURFACES:
                c = (dist[kind] - body.radius - getattr(self.distances, kind)).amin(dim=-1)
                worst[kind] = c if kind not in worst else torch.minimum(worst[kind], c)
        return worst

    def clearances(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per configuration, the margin (m) by which each safety distance is kept.

        ``{"self", "wall", "ground", "arch"}`` -> tensor ``q.shape[:-1]``; negative
        means violated. Self: clamped segment-segment distance of every listed pair
        less both radii and ``d_self``. Tunnel: every sample point of every capsule,
        inflated by its radius, against each surface.
        """
        return self.clearances_from_frames(self.boom.frames(q))

    def clearances_from_frames(self, frames: torch.Tensor) -> dict[str, torch.Tensor]:
        ends = {name: self.boom.capsule_ends(frames, name) for name in self.boom.bodies}
        out = self._tunnel_clearances((self.boom.bodies[n], *ends[n]) for n in self.boom.bodies)
        selfc = None
        for a, b in self.boom.self_pairs:
            dist, _, _ = segment_distance(*ends[a], *ends[b])
            c = dist - self.boom.bodies[a].radius - self.boom.bodies[b].radius - self.distances.self
            selfc = c if selfc is None else torch.minimum(selfc, c)
        if selfc is None:  # no self pairs: self collision cannot happen
            selfc = torch.full(frames.shape[:-3], math.inf, dtype=frames.dtype, device=frames.device)
        out["self"] = selfc
        return {k: out[k] for k in SAFETY_KINDS}

    def clearances_with_jacobians(self, frames: torch.Tensor) -> tuple[dict[str, torch.Tensor], dict]:
        """The clearances of :meth:`clearances_from_frames` and their gradients ``(..., n_joints)``
        with respect to the joints, from one forward pass (no autograd: solvers call it every step).

        A clearance is a minimum over sample points (tunnel) or the closest points of two segments
        (self), so its gradient is the gradient at the minimising point: the surface's unit normal
        (or the unit vector between the closest points) times that point's geometric Jacobian. The
        feed's checked length is fixed (its length is), so the truncation adds no term."""
        boom = self.boom
        axes = boom.joint_axes(frames)
        ends, jacs = {}, {}
        for name, body in boom.bodies.items():
            ends[name] = (boom.point(frames, body.start), boom.point(frames, body.end))
            jacs[name] = tuple(boom.point_jacobian(frames, p, spec.frame, axes)[0]
                               for p, spec in zip(ends[name], (body.start, body.end), strict=True))
        values: dict[str, torch.Tensor] = {}
        grads: dict[str, torch.Tensor] = {}
        for name, body in boom.bodies.items():
            pts, frac = self._tunnel_points(body, *ends[name])
            dist = self.tunnel.surface_distances(pts[..., 1], pts[..., 2])
            for kind in SURFACES:
                c, i = (dist[kind] - body.radius - getattr(self.distances, kind)).min(dim=-1)
                p = torch.gather(pts, -2, i[..., None, None].expand(*i.shape, 1, 3)).squeeze(-2)
                a = torch.gather(frac, -1, i.unsqueeze(-1))[..., None]
                jp = (1 - a) * jacs[name][0] + a * jacs[name][1]
                gy, gz = self.tunnel.surface_gradients(p[..., 1], p[..., 2])[kind]
                g = gy.unsqueeze(-1) * jp[..., 1, :] + gz.unsqueeze(-1) * jp[..., 2, :]
                _keep_min(values, grads, kind, c, g)
        for a_name, b_name in boom.self_pairs:
            dist, s, t = segment_distance(*ends[a_name], *ends[b_name])
            c = dist - boom.bodies[a_name].radius - boom.bodies[b_name].radius - self.distances.self
            (a0, a1), (b0, b1) = ends[a_name], ends[b_name]
            s_, t_ = s[..., None], t[..., None]
            u = ((a0 + s_ * (a1 - a0)) - (b0 + t_ * (b1 - b0))) / dist.clamp_min(1e-12)[..., None]
            s_, t_ = s_[..., None], t_[..., None]
            j_rel = ((1 - s_) * jacs[a_name][0] + s_ * jacs[a_name][1]
                     - (1 - t_) * jacs[b_name][0] - t_ * jacs[b_name][1])
            _keep_min(values, grads, "self", c, (u.unsqueeze(-1) * j_rel).sum(-2))
        if "self" not in values:  # no self pairs: self collision cannot happen
            values["self"] = torch.full(frames.shape[:-3], math.inf, dtype=frames.dtype, device=frames.device)
            grads["self"] = torch.zeros(*frames.shape[:-3], boom.n_joints, dtype=frames.dtype, device=frames.device)
        return {k: values[k] for k in SAFETY_KINDS}, {k: grads[k] for k in SAFETY_KINDS}

    def tool_body_clearances(self, p: torch.Tensor, z: torch.Tensor) -> dict[str, torch.Tensor]:
        """Tunnel clearances of the bodies fixed to the tool frame, from a hole pose alone.

        Used to reject holes that no joint solution can drill: if the feed beam at
        the hole already violates a tunnel safety distance, so does every solution.
        """
        tool = self.boom.tool_index
        bodies = [b for b in self.boom.bodies.values() if b.start.frame == tool and b.end.frame == tool]
        if not bodies:
            raise ConfigError(f"boom '{self.boom.name}' has no body fixed to the tool frame")
        return self._tunnel_clearances((b, p + b.start.along_z * z, p + b.end.along_z * z) for b in bodies)

    # Both views below derive from the same clearances.
    @staticmethod
    def violations(clearances: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {k: c < 0 for k, c in clearances.items()}

    @staticmethod
    def penalties(clearances: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Hinge of each clearance (paper 000 eqs. 14-15): zero exactly where the check passes."""
        return {k: torch.relu(-c) for k, c in clearances.items()}


def _keep_min(values: dict, grads: dict, kind: str, c: torch.Tensor, g: torch.Tensor) -> None:
    """Keep, per configuration, the smaller clearance of ``kind`` and its gradient."""
    if kind not in values:
        values[kind], grads[kind] = c, g
        return
    take = c < values[kind]
    values[kind] = torch.where(take, c, values[kind])
    grads[kind] = torch.where(take.unsqueeze(-1), g, grads[kind])
