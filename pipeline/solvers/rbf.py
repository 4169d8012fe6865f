"""Exact-interpolation Gaussian RBF network (paper 001, MATLAB ``newrbe``), as an IK solver.

Training data as paper 001 builds it: joints uniform over their ranges with one prismatic
joint locked (paper 001 locks its last one; here jumbo8's ``q8``), the tool pose by forward
kinematics written as position + RPY angles, inputs and outputs min-max normalised to [-1, 1]
(``mapminmax``). One Gaussian centre per training sample with ``newrbe``'s width: a unit is 0.5
at distance ``spread`` from its centre. The output weights solve ``Phi W = Y`` exactly (no bias:
with one centre per sample the system is already square; decided here).

A hole fixes position and drilling direction but not the roll about the drill axis, while the
network wants a full pose: a hole's rotation is the smallest rotation taking the tool's drilling
axis at the home pose onto the hole direction, applied to the home rotation (decided here).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rotations import align, rpy
from pipeline.solvers.base import FrameTargets, HoleTargets, JointSpace, Solver, Targets, tool_transform


class MinMax:
    """``mapminmax``: each column to [-1, 1] over the training data (constant columns to 0)."""

    def __init__(self, data: torch.Tensor):
        self.lo, self.hi = data.min(dim=0).values, data.max(dim=0).values
        self.span = torch.where(self.hi > self.lo, self.hi - self.lo, torch.ones_like(self.hi))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return 2 * (x - self.lo) / self.span - 1

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        return self.lo + (y + 1) * self.span / 2


class ExactRBF:
    """Gaussian RBF interpolant through every training pair ``(X, Y)``."""

    def __init__(self, X: torch.Tensor, Y: torch.Tensor, spread: float = 1.0):
        if spread <= 0:
            raise ConfigError(f"rbf.spread = {spread}: must be > 0")
        if X.shape[0] != Y.shape[0]:
            raise InputError(f"RBF: {X.shape[0]} inputs but {Y.shape[0]} outputs")
        self.x_map, self.y_map = MinMax(X), MinMax(Y)
        self.centres = self.x_map.forward(X.double())
        self.b = math.sqrt(math.log(2.0)) / spread  # newrbe: radbas(b * dist) = 0.5 at dist = spread
        Phi = self.kernel(self.centres)
        self.weights = torch.linalg.solve(Phi, self.y_map.forward(Y.double()))

    def kernel(self, Xn: torch.Tensor) -> torch.Tensor:
        return torch.exp(-((self.b * torch.cdist(Xn, self.centres)) ** 2))

    def __call__(self, X: torch.Tensor) -> torch.Tensor:
        return self.y_map.inverse(self.kernel(self.x_map.forward(X.double())) @ self.weights)


def frame_features(T: torch.Tensor) -> torch.Tensor:
    """Paper 001's network input: ``[roll, pitch, yaw, x, y, z]`` of tool frames."""
    return torch.cat([rpy(T[..., :3, :3]), T[..., :3, 3]], dim=-1)


class RBFSolver(Solver):
    """Paper 001's RBF IK: sample, fit once (``fit``), then one kernel product per batch."""

    name = "rbf"

    def __init__(
        self, boom: Boom, samples: int = 10_000, train: int = 8_800, spread: float = 1.0,
        locks: Mapping[str, float] | None = None, seed: int = 0, name: str = "rbf",
    ):
        super().__init__(boom)
        if not 0 < train <= samples:
            raise ConfigError(f"rbf: need 0 < train <= samples, got train={train}, samples={samples}")
        self.space = JointSpace(boom, locks)
        self.samples, self.train, self.spread, self.seed, self.name = samples, train, spread, seed, name
        self.net: ExactRBF | None = None
        self.fit_set: tuple[torch.Tensor, torch.Tensor] | None = None  # (features, free joints)
        self.test_set: tuple[torch.Tensor, torch.Tensor] | None = None
        home = torch.zeros(boom.n_joints, dtype=torch.float64)
        self.home_rotation = tool_transform(boom, home)[:3, :3]

    def fit(self) -> RBFSolver:
        g = torch.Generator().manual_seed(self.seed)
        x = self.space.uniform((self.samples,), g)
        feats = frame_features(tool_transform(self.boom, self.space.full(x)))
        self.fit_set = feats[: self.train], x[: self.train]
        self.test_set = feats[self.train:], x[self.train:]
        self.net = ExactRBF(*self.fit_set, self.spread)
        return self

    def hole_frames(self, targets: HoleTargets) -> torch.Tensor:
        """Full tool rotations for holes: the home rotation turned onto each hole direction."""
        d = targets.pose[:, 3:] - targets.pose[:, :3]
        d = d / d.norm(dim=-1, keepdim=True)
        return align(self.home_rotation[:, 2], d) @ self.home_rotation

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        if self.net is None:
            self.fit()
        if isinstance(targets, HoleTargets):
            feats = torch.cat([rpy(self.hole_frames(targets)), targets.pose[:, :3].double()], dim=-1)
        elif isinstance(targets, FrameTargets):
            feats = torch.cat([rpy(targets.rotation.double()), targets.position.double()], dim=-1)
        else:
            raise InputError(f"{self.name}: unsupported targets {type(targets).__name__}")
        x = self.space.clamp(self.net(feats))  # the interpolant may leave the ranges between centres
        return self.space.full(x), torch.ones(len(targets), dtype=torch.long)
