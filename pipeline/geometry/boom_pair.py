"""Boom-boom clearance of two booms of a rig (docs/reference.md, section 7), batched over both booms' configurations.

For booms a != b, the distance of every capsule of a (jumbo8: boom A-C, feed H0-H) to every capsule
of b is the clamped segment-segment distance of their axes (:func:`~pipeline.geometry.collision.
segment_distance`, the one self-collision uses) less the two radii; the clearance is the smallest of
them less ``d_boom``, so it is negative exactly when d_boom is broken, as the safety model's clearances.

Both booms' frames must be in one frame, the rig frame (:meth:`pipeline.geometry.rig.MountedBoom.frames`):
this module knows nothing of bases. Frames broadcast against each other, so ``(N, 1, ...)`` against
``(1, M, ...)`` gives every pairing of N configurations of a with M of b.
"""

from __future__ import annotations

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import segment_distance
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rotations import safe_norm


class BoomPair:
    """Clearances between the capsules of boom ``a`` and boom ``b`` (both :class:`Boom`, rig-frame frames)."""

    def __init__(self, a: Boom, b: Boom, d_boom: float = 0.3):
        for boom in (a, b):
            if not boom.bodies:
                raise ConfigError(f"boom '{boom.name}' defines no collision bodies; boom-boom clearance needs them")
        if not d_boom >= 0:
            raise ConfigError(f"d_boom = {d_boom!r}: a safety distance cannot be below zero")
        self.a, self.b, self.d_boom = a, b, float(d_boom)
        self.names_a, self.names_b = list(a.bodies), list(b.bodies)
        self._consts: dict = {}

    def _c(self, boom: Boom, dtype, device) -> dict[str, torch.Tensor]:
        key = (boom is self.a, dtype, device)
        if key not in self._consts:
            bodies = list(boom.bodies.values())
            self._consts[key] = {
                "radius": torch.tensor([b.radius for b in bodies], dtype=dtype, device=device),
                "frames": torch.tensor([p.frame for b in bodies for p in (b.start, b.end)], device=device),
            }
        return self._consts[key]

    @staticmethod
    def _ends(boom: Boom, frames: torch.Tensor) -> torch.Tensor:
        """Every capsule's axis ends ``(..., bodies, 2, 3)`` (a loop over bodies, batched over configurations)."""
        return torch.stack([torch.stack(boom.capsule_ends(frames, name), dim=-2) for name in boom.bodies], dim=-3)

    def _pairs(self, frames_a: torch.Tensor, frames_b: torch.Tensor):
        """Per capsule pair ``(..., bodies_a, bodies_b)``: distance less radii, the closest-point
        parameters ``s`` (on a) and ``t`` (on b); and both booms' capsule ends."""
        ea, eb = self._ends(self.a, frames_a), self._ends(self.b, frames_b)
        ra = self._c(self.a, frames_a.dtype, frames_a.device)["radius"]
        rb = self._c(self.b, frames_b.dtype, frames_b.device)["radius"]
        pa, qa = ea[..., :, None, 0, :], ea[..., :, None, 1, :]  # (..., A, 1, 3)
        pb, qb = eb[..., None, :, 0, :], eb[..., None, :, 1, :]  # (..., 1, B, 3)
        dist, s, t = segment_distance(pa, qa, pb, qb)
        return dist - ra[:, None] - rb[None, :], s, t, ea, eb

    def distances(self, frames_a: torch.Tensor, frames_b: torch.Tensor) -> torch.Tensor:
        """Surface distance (m) of every capsule of a to every capsule of b: ``(..., bodies_a, bodies_b)``
        (negative: the capsules overlap; the axes' distance less the radii)."""
        return self._pairs(frames_a, frames_b)[0]

    def clearance(self, frames_a: torch.Tensor, frames_b: torch.Tensor) -> torch.Tensor:
        """The smallest capsule distance less ``d_boom``: ``(...,)``, negative when d_boom is broken."""
        return self.distances(frames_a, frames_b).flatten(-2).amin(-1) - self.d_boom

    def distances_with_jacobians(self, frames_a: torch.Tensor, frames_b: torch.Tensor):
        """:meth:`distances` and their gradients with respect to each boom's joints, from one forward
        pass (no autograd: solver rows use them): ``d (..., A, B)``, ``grad_a (..., A, B, n_a)``,
        ``grad_b (..., A, B, n_b)``.

        A clamped segment distance is the distance of its closest points, so its gradient is the unit
        vector between them times each closest point's geometric Jacobian (the points move with their
        capsule at fixed ``s``, ``t``: the minimisation adds no term), as the safety model's self rows."""
        d, s, t, ea, eb = self._pairs(frames_a, frames_b)
        ca, cb = self._c(self.a, frames_a.dtype, frames_a.device), self._c(self.b, frames_b.dtype, frames_b.device)
        ja = self.a.points_jacobian(frames_a, ea.flatten(-3, -2), ca["frames"]).unflatten(-3, (-1, 2))
        jb = self.b.points_jacobian(frames_b, eb.flatten(-3, -2), cb["frames"]).unflatten(-3, (-1, 2))
        s_, t_ = s[..., None], t[..., None]
        on_a = ea[..., :, None, 0, :] + s_ * (ea[..., :, None, 1, :] - ea[..., :, None, 0, :])
        on_b = eb[..., None, :, 0, :] + t_ * (eb[..., None, :, 1, :] - eb[..., None, :, 0, :])
        gap = on_a - on_b  # (..., A, B, 3)
        u = (gap / safe_norm(gap).clamp_min(1e-12)[..., None]).unsqueeze(-1)
        s_, t_ = s_[..., None], t_[..., None]
        j_on_a = (1 - s_) * ja[..., :, None, 0, :, :] + s_ * ja[..., :, None, 1, :, :]  # (..., A, B, 3, n_a)
        j_on_b = (1 - t_) * jb[..., None, :, 0, :, :] + t_ * jb[..., None, :, 1, :, :]
        return d, (u * j_on_a).sum(-2), -(u * j_on_b).sum(-2)

    def clearance_with_jacobians(self, frames_a: torch.Tensor, frames_b: torch.Tensor):
        """:meth:`clearance` and its gradients ``(..., n_a)``, ``(..., n_b)``: those of the nearest pair."""
        d, ga, gb = self.distances_with_jacobians(frames_a, frames_b)
        value, i = d.flatten(-2).min(-1)
        pick = lambda g: torch.gather(  # noqa: E731  the nearest pair's gradient row
            g.flatten(-3, -2), -2, i[..., None, None].expand(*i.shape, 1, g.shape[-1])).squeeze(-2)
        return value - self.d_boom, pick(ga), pick(gb)
