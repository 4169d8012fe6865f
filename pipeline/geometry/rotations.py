"""Rotation and vector helpers shared by the kinematics, the tunnel distances and the solvers.

Everything is batched over leading dimensions and safe to differentiate where it matters (norms at
the origin, small angles)."""

from __future__ import annotations

import torch

from pipeline.core.errors import InputError


def _safe_sqrt(sq: torch.Tensor) -> torch.Tensor:
    """Square root of a sum of squares whose gradient is 0 (not NaN) where the sum is 0."""
    pos = sq > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, sq, torch.ones_like(sq))), torch.zeros_like(sq))


def safe_norm(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Euclidean norm whose gradient is 0 (not NaN) at the origin."""
    return _safe_sqrt((x * x).sum(dim))


def safe_hypot(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """:func:`safe_norm` of ``stack([u, v], -1)`` with the same float operations (so the same bits and
    gradients), without building the stacked tensor and reducing over its short last axis: the tunnel
    distances take the norm of one (y, z) pair per checked point, in every training step. ``square``,
    not ``u * u``: a product of a tensor with itself hands autograd two terms, which would reach ``u``'s
    other gradients one at a time and round differently from the stacked form."""
    return _safe_sqrt(u.square() + v.square())


def angle_between(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Angle (rad) between vectors ``(..., 3)``; atan2(|u x v|, u.v) stays accurate for the small
    angles that matter here, unlike arccos."""
    u, v = torch.broadcast_tensors(u, v)
    return torch.atan2(torch.linalg.vector_norm(torch.linalg.cross(u, v, dim=-1), dim=-1), (u * v).sum(-1))


def rotation_angle(R_hat: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Angle (rad) of the rotation taking ``R`` to ``R_hat``; atan2 keeps small angles exact."""
    M = R.transpose(-1, -2) @ R_hat
    cos = 0.5 * (M.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0)
    skew = M - M.transpose(-1, -2)
    sin = 0.5 * torch.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1).norm(dim=-1)
    return torch.atan2(sin, cos)


def skew(v: torch.Tensor) -> torch.Tensor:
    """The cross-product matrix ``(..., 3, 3)`` of ``v (..., 3)``: ``skew(v) @ u == v x u``."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v.unbind(-1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*v.shape[:-1], 3, 3)


def rpy(R: torch.Tensor) -> torch.Tensor:
    """Roll, pitch, yaw ``(..., 3)`` of ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    roll = torch.atan2(R[..., 2, 1], R[..., 2, 2])
    pitch = torch.atan2(-R[..., 2, 0], torch.hypot(R[..., 2, 1], R[..., 2, 2]))
    yaw = torch.atan2(R[..., 1, 0], R[..., 0, 0])
    return torch.stack([roll, pitch, yaw], dim=-1)


def align(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Smallest rotation ``(..., 3, 3)`` taking unit vector ``a`` onto unit vector ``b`` (Rodrigues);
    ``a`` and ``b`` must not be opposite (holes lie within a cone around the home direction)."""
    v = torch.linalg.cross(a.expand_as(b), b)
    c = (a * b).sum(-1)
    if (c <= -1 + 1e-9).any():
        raise InputError("hole direction opposite to the tool's home drilling axis: no unique rotation")
    K = skew(v)
    eye = torch.eye(3, dtype=v.dtype, device=v.device).expand_as(K)
    return eye + K + (K @ K) / (1 + c)[..., None, None]


def se3_exp(xi: torch.Tensor) -> torch.Tensor:
    """``exp`` of twists ``(..., 6)`` = (omega, v) as ``(..., 4, 4)`` transforms (Rodrigues).

    Small angles use the Taylor series of the coefficients, and the closed form sees a guarded
    angle, so values and derivatives stay finite at zero (where the result is exactly ``I``).
    """
    w, v = xi[..., :3], xi[..., 3:]
    th2 = (w * w).sum(-1)
    small = th2 < 1e-6
    th2_safe = torch.where(small, torch.ones_like(th2), th2)
    th = torch.sqrt(th2_safe)
    a = torch.where(small, 1 - th2 / 6 + th2 * th2 / 120, torch.sin(th) / th)
    b = torch.where(small, 0.5 - th2 / 24 + th2 * th2 / 720, (1 - torch.cos(th)) / th2_safe)
    c = torch.where(small, 1 / 6 - th2 / 120 + th2 * th2 / 5040, (th - torch.sin(th)) / (th2_safe * th))
    W = skew(w)
    W2 = W @ W
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand_as(W)
    R = eye + a[..., None, None] * W + b[..., None, None] * W2
    V = eye + b[..., None, None] * W + c[..., None, None] * W2
    t = (V @ v.unsqueeze(-1)).squeeze(-1)
    bottom = torch.zeros(*xi.shape[:-1], 1, 4, dtype=xi.dtype, device=xi.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([torch.cat([R, t.unsqueeze(-1)], -1), bottom], -2)
