"""Training objectives of paper 000: eq. 6 (SIKM), eq. 7 (UIKM), eq. 16 (CUIKM)."""

from __future__ import annotations

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SAFETY_KINDS

POSE_LOSSES = ("mse", "norm")


def joint_loss(unit_hat: torch.Tensor, unit_target: torch.Tensor) -> torch.Tensor:
    """Eq. 6 with joints normalised by their ranges: mean squared error of range fractions."""
    return ((unit_hat - unit_target) ** 2).sum(-1).mean()


def pose_loss(pose_hat: torch.Tensor, pose: torch.Tensor, kind: str = "mse") -> torch.Tensor:
    """Eq. 7. ``mse``: mean squared 6-D distance (the paper). ``norm``: mean hole-seeking
    error (start and preview distances, not squared), whose gradient does not fade as the
    error shrinks, which is what millimetre accuracy needs."""
    diff = pose_hat - pose
    if kind == "mse":
        return (diff**2).sum(-1).mean()
    if kind == "norm":
        e_s = torch.sqrt((diff[..., :3] ** 2).sum(-1) + 1e-12)
        e_p = torch.sqrt((diff[..., 3:] ** 2).sum(-1) + 1e-12)
        return (0.5 * (e_s + e_p)).mean()
    raise ConfigError(f"method.pose_loss = {kind!r}; expected one of {POSE_LOSSES}")


def safety_terms(penalties: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Eqs. 14-15: the mean hinge penalty of each kind over the batch."""
    return {f"l_{k}": penalties[k].mean() for k in SAFETY_KINDS}


def total_loss(terms: dict[str, torch.Tensor], lam: float, mu: float) -> torch.Tensor:
    """Eq. 16: ``lam * l_pos + mu * (l_self + l_wall + l_ground + l_arch)``."""
    return lam * terms["l_pos"] + mu * sum(terms[f"l_{k}"] for k in SAFETY_KINDS)
