"""Training objectives of paper 000: eq. 6 (SIKM), eq. 7 (UIKM), eq. 16 (CUIKM)."""

from __future__ import annotations

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SAFETY_KINDS

POSE_LOSSES = ("mse", "norm")
JOINT_METRICS = ("range", "pose")


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
    """Eq. 16: ``lam * l_pos + mu * (l_self + l_wall + l_ground + l_arch)`` (UIKM: ``mu = 0``, no
    penalty terms needed)."""
    if mu == 0:
        return lam * terms["l_pos"]
    return lam * terms["l_pos"] + mu * sum(terms[f"l_{k}"] for k in SAFETY_KINDS)


def label_pose_loss(boom, q_hat: torch.Tensor, q_label: torch.Tensor, kind: str) -> torch.Tensor:
    """The joint error ``q_hat - q_label`` measured by what it does to the hole pose, to first
    order at the label: ``pose_loss(J(q_label) dq)``. Eq. 6 weighs each joint by its range, so a
    swing error a hundredth of its range (about 0.9 deg, 125 mm at the face) costs as much as a
    hundredth of the feed extension (25 mm); this weighs them by the millimetres they cost. The
    Jacobian is the label's, held fixed: the loss is still a distance to the label (a quadratic
    form in ``dq`` for ``mse``), never the forward kinematics of the prediction."""
    with torch.no_grad():
        jac = boom.pose6_jacobian(boom.frames(q_label))  # (B, 6, n_joints)
    moved = (jac @ (q_hat - q_label).unsqueeze(-1)).squeeze(-1)
    return pose_loss(moved, torch.zeros_like(moved), kind)


def supervised_loss(terms: dict[str, torch.Tensor], mu: float) -> torch.Tensor:
    """Eq. 6 (``l_joint``), plus its pose-metric form ``l_joint_pose`` where computed (eq. 6 stays
    beside it: it alone pins the joints along the boom's redundancy, which the pose ignores), and
    with ``mu > 0`` eq. 16's safety penalties: ``+ mu * (l_self + l_wall + l_ground + l_arch)``.
    No term evaluates the pose the network reaches, so what it learns of the pose it learns from
    the labels alone (the row stays supervised); the penalties push it off labels that pass a
    surface closer than the training safety distances."""
    loss = terms["l_joint"] + terms.get("l_joint_pose", 0.0)
    if mu == 0:
        return loss
    return loss + mu * sum(terms[f"l_{k}"] for k in SAFETY_KINDS)
