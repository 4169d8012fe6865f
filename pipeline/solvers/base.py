"""One interface for every IK solver: a batch of targets in; joints, per-target errors,
iteration counts and wall time out.

Targets come in two kinds:

* :class:`HoleTargets` -- 6-D hole poses ``[p, p']`` (paper 000 eq. 4): collar point and
  preview point, so position plus drilling direction (roll about the drill axis is free);
* :class:`FrameTargets` -- full tool poses (position and rotation), as papers 002 and 003 use.

Both compute their errors from tool transforms of any leading shape, so population-based
solvers evaluate whole swarms ``(targets, particles, ...)`` in one call.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.kinematics import Boom, pose_errors
from pipeline.geometry.rotations import rotation_angle


def tool_transform(boom: Boom, q: torch.Tensor) -> torch.Tensor:
    """Tool frame ``(..., 4, 4)`` of joint vectors ``q (..., n_joints)``."""
    return boom.frames(q)[..., boom.tool_index, :, :]


def _against(x: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    """Reshape per-target values ``(B, *rest)`` to broadcast against ``T (B, ..., 4, 4)``."""
    return x.reshape(x.shape[0], *([1] * (T.ndim - 3)), *x.shape[1:])


@dataclass(frozen=True)
class HoleTargets:
    """Holes ``(B, 6)``: collar ``p`` and preview point ``p' = p + D z`` (metres)."""

    pose: torch.Tensor
    depth: float

    def __post_init__(self):
        if self.pose.ndim != 2 or self.pose.shape[-1] != 6:
            raise InputError(f"hole targets: expected shape (n, 6), got {tuple(self.pose.shape)}")
        if not torch.isfinite(self.pose).all():
            bad = (~torch.isfinite(self.pose).all(-1)).nonzero().flatten()[:5].tolist()
            raise InputError(f"hole targets: non-finite values in rows {bad}")

    def __len__(self) -> int:
        return self.pose.shape[0]

    @property
    def position(self) -> torch.Tensor:
        """Collar points ``(B, 3)``: the position part of the target."""
        return self.pose[:, :3]

    def subset(self, index) -> HoleTargets:
        return HoleTargets(self.pose[index], self.depth)

    def errors(self, T: torch.Tensor) -> dict[str, torch.Tensor]:
        """Spec section 4 errors (m, rad) of tool frames ``T`` (:func:`pose_errors`): position =
        collar error, orientation = direction error, plus preview and hole-seeking error."""
        p, z = T[..., :3, 3], T[..., :3, 2]
        err = pose_errors(torch.cat([p, p + self.depth * z], dim=-1), _against(self.pose.to(T), T))
        return {"position": err["start"], "orientation": err["direction"], "preview": err["preview"],
                "hole": err["hole"]}

    def residual(self, T: torch.Tensor) -> torch.Tensor:
        """The 6 equations of paper 000's NM: ``pose6(q) - P`` (m)."""
        p, z = T[..., :3, 3], T[..., :3, 2]
        target = _against(self.pose.to(T), T)
        return torch.cat([p - target[..., :3], p + self.depth * z - target[..., 3:]], dim=-1)


@dataclass(frozen=True)
class FrameTargets:
    """Full tool poses: ``position (B, 3)`` (m) and ``rotation (B, 3, 3)``."""

    position: torch.Tensor
    rotation: torch.Tensor

    def __post_init__(self):
        n = self.position.shape[0]
        if self.position.shape != (n, 3) or self.rotation.shape != (n, 3, 3):
            raise InputError(
                f"frame targets: expected position (n, 3) and rotation (n, 3, 3), got "
                f"{tuple(self.position.shape)} and {tuple(self.rotation.shape)}"
            )

    @classmethod
    def from_transforms(cls, T: torch.Tensor) -> FrameTargets:
        return cls(T[..., :3, 3].clone(), T[..., :3, :3].clone())

    def __len__(self) -> int:
        return self.position.shape[0]

    def subset(self, index) -> FrameTargets:
        return FrameTargets(self.position[index], self.rotation[index])

    def errors(self, T: torch.Tensor) -> dict[str, torch.Tensor]:
        position = (T[..., :3, 3] - _against(self.position.to(T), T)).norm(dim=-1)
        orientation = rotation_angle(T[..., :3, :3], _against(self.rotation.to(T), T))
        return {"position": position, "orientation": orientation}

    def residual(self, T: torch.Tensor) -> torch.Tensor:
        """Position error and the orientation error vector 0.5 * sum(r_hat_i x r_i) (Siciliano)."""
        R_hat, R = T[..., :3, :3], _against(self.rotation.to(T), T)
        e_o = 0.5 * torch.linalg.cross(R_hat, R.expand_as(R_hat), dim=-2).sum(-1)
        return torch.cat([T[..., :3, 3] - _against(self.position.to(T), T), -e_o], dim=-1)


Targets = HoleTargets | FrameTargets


def require(checks: Mapping[str, bool], what: str, value) -> None:
    """Raise :class:`ConfigError` naming every failed condition of ``what`` and its value."""
    failed = [name for name, ok in checks.items() if not ok]
    if failed:
        raise ConfigError(f"{what}: {', '.join(failed)} required; got {value}")


class JointSpace:
    """The joints a solver searches: the boom's free joints less any extra locks.

    ``locks`` maps joint names to fixed values in SI units (rad or m)."""

    def __init__(self, boom: Boom, locks: Mapping[str, float] | None = None):
        locks = dict(locks or {})
        unknown = sorted(set(locks) - set(boom.joint_names))
        if unknown:
            raise InputError(f"locks: unknown joint(s) {unknown}; boom '{boom.name}' has {boom.joint_names}")
        lo, hi = boom.limits()
        self.boom = boom
        self.fixed = lo.clone()  # locked joints sit at their lock value (lower == upper)
        for name, value in locks.items():
            i = boom.joint_names.index(name)
            if not lo[i] <= value <= hi[i]:
                raise InputError(f"locks.{name} = {value}: outside the joint range [{lo[i]:.4g}, {hi[i]:.4g}]")
            self.fixed[i] = value
        self.free = [i for i, j in enumerate(boom.joints) if j.locked is None and j.name not in locks]
        self.lower, self.upper = lo[self.free], hi[self.free]
        self.revolute = torch.tensor([boom.joints[i].revolute for i in self.free])

    @property
    def n(self) -> int:
        return len(self.free)

    @property
    def names(self) -> list[str]:
        return [self.boom.joint_names[i] for i in self.free]

    def full(self, x: torch.Tensor) -> torch.Tensor:
        """Full joint vectors ``(..., n_joints)`` from free-joint values ``(..., n)``."""
        q = self.fixed.to(x).expand(*x.shape[:-1], self.boom.n_joints).clone()
        q[..., self.free] = x
        return q

    def clamp(self, x: torch.Tensor) -> torch.Tensor:
        return torch.maximum(torch.minimum(x, self.upper.to(x)), self.lower.to(x))

    def uniform(self, shape: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:
        u = torch.rand(*shape, self.n, generator=generator, dtype=torch.float64)
        return self.lower + u * (self.upper - self.lower)


@dataclass
class SolveResult:
    """Joints ``q (B, n_joints)``, errors per target (m / rad), iterations per target, wall time;
    solvers that judge safety add a status per target and its clearances (m)."""

    q: torch.Tensor
    errors: dict[str, torch.Tensor]
    iterations: torch.Tensor
    wall_s: float
    status: list[str] | None = None
    clearances: dict[str, torch.Tensor] | None = None


class Solver:
    """Base class: subclasses implement ``_solve(targets) -> (q, iterations)``."""

    name = "solver"

    def __init__(self, boom: Boom):
        self.boom = boom

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def joints(self, targets: Targets) -> torch.Tensor:
        """Only the joints ``(B, n_joints)`` float64: no timing, no error evaluation (a solver that
        starts another one needs nothing more)."""
        with torch.no_grad():
            return self._solve(targets)[0].double()

    def solve(self, targets: Targets) -> SolveResult:
        if len(targets) == 0:
            raise InputError(f"{self.name}: no targets to solve")
        start = time.perf_counter()
        with torch.no_grad():
            q, iterations = self._solve(targets)
        wall = time.perf_counter() - start
        self.boom.check_joints(q, f"{self.name} output")
        with torch.no_grad():
            errors = targets.errors(tool_transform(self.boom, q.double()))
        return SolveResult(q.double(), errors, iterations, wall)


class NetworkSolver(Solver):
    """A trained IK network (SIKM / UIKM / CUIKM) behind the solver interface: one forward pass."""

    def __init__(self, boom: Boom, model: torch.nn.Module, name: str = "network"):
        super().__init__(boom)
        self.model = model.eval()
        self.name = name

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        if not isinstance(targets, HoleTargets):
            raise InputError(f"{self.name}: a network trained on hole poses needs HoleTargets")
        param = next(self.model.parameters())
        q = self.model(targets.pose.to(param)).double().to(targets.pose.device)  # where the holes are
        return q, torch.ones(len(targets), dtype=torch.long)
