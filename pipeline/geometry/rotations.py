"""Rotation and vector helpers shared by the kinematics, the tunnel distances and the solvers.

Everything is batched over leading dimensions and safe to differentiate where it matters (norms at
the origin, small angles)."""

from __future__ import annotations

import torch

from pipeline.core.errors import InputError


def safe_norm(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Euclidean norm whose gradient is 0 (not NaN) at the origin."""
    sq = (x * x).sum(dim)
    pos = sq > 0
    return torch.where(pos, torch.sqrt(torch.where(pos, sq, torch.ones_like(sq))), torch.zeros_like(sq))


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
