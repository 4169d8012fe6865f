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
from collections.abc import Mapping, Sequence

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rotations import align, rpy, skew
from pipeline.optim.scaling import MinMax
from pipeline.solvers.base import FrameTargets, HoleTargets, JointSpace, Solver, Targets, tool_transform


class ExactRBF:
    """Gaussian RBF interpolant through every training pair ``(X, Y)`` (``reg`` > 0: a ridge fit,
    ``(Phi + reg I) W = Y``, which stays well posed where the exact system is numerically singular)."""

    CHUNK = 4096  # rows of the kernel matrix at a time: (4096 x 8800) float64 is ~290 MB

    def __init__(self, X: torch.Tensor, Y: torch.Tensor, spread: float = 1.0, reg: float = 0.0):
        if spread <= 0:
            raise ConfigError(f"rbf.spread = {spread}: must be > 0")
        if reg < 0:
            raise ConfigError(f"rbf.reg = {reg}: must be >= 0")
        if X.shape[0] != Y.shape[0]:
            raise InputError(f"RBF: {X.shape[0]} inputs but {Y.shape[0]} outputs")
        self.x_map, self.y_map = MinMax.fit(X), MinMax.fit(Y)
        self.centres = self.x_map.forward(X.double())
        self.b = math.sqrt(math.log(2.0)) / spread  # newrbe: radbas(b * dist) = 0.5 at dist = spread
        Phi = self.kernel(self.centres)
        if reg:
            Phi.diagonal().add_(reg)
        self.weights = torch.linalg.solve(Phi, self.y_map.forward(Y.double()))

    def kernel(self, Xn: torch.Tensor) -> torch.Tensor:
        return torch.exp(-((self.b * torch.cdist(Xn, self.centres)) ** 2))

    def __call__(self, X: torch.Tensor) -> torch.Tensor:
        Xn = self.x_map.forward(X.double())
        out = torch.cat([self.kernel(Xn[i : i + self.CHUNK]) @ self.weights for i in range(0, len(Xn), self.CHUNK)])
        return self.y_map.inverse(out)


def frame_features(T: torch.Tensor, home: torch.Tensor) -> torch.Tensor:
    """Paper 001's network input: ``[roll, pitch, yaw, x, y, z]`` of tool frames, the angles of the
    tool's rotation from its home orientation, in the base frame (``R home^T``). Decided here: the
    angles of jumbo8's tool rotation itself sit next to the RPY singularity (pitch +-90 deg) and wrap
    at +-180 deg over the working postures, which no interpolant survives; measured from home they
    stay within about +-110 / 60 / 65 deg."""
    return torch.cat([rpy(T[..., :3, :3] @ home.transpose(-1, -2)), T[..., :3, 3]], dim=-1)


class RBFSolver(Solver):
    """Paper 001's RBF IK: sample, fit once (``fit``), then one kernel product per batch.

    Paper 001 locks its last prismatic joint and keeps joint 4 at its initial value (the boom held
    square to the face), leaving 6 joints for a 6-D pose, so the inverse is unique. The jumbo8
    equivalent (``locks``): the feed extension ``q8`` and the boom rotation ``q4``. Samples are drawn
    within ``box`` (the working box; None: the full ranges). Options beyond the paper (the
    ``rbf_tuned`` entry): ``spreads`` picks the spread on the held-out samples, ``reg`` a ridge term,
    and ``roll_grid`` tries that many rolls of each hole about its axis (a hole leaves the roll free)
    and keeps the answer whose forward kinematics hits the hole best."""

    name = "rbf"

    def __init__(
        self, boom: Boom, samples: int = 10_000, train: int = 8_800, spread: float = 1.0,
        locks: Mapping[str, float] | None = None, seed: int = 0, name: str = "rbf",
        box: tuple[torch.Tensor, torch.Tensor] | None = None, spreads: Sequence[float] = (), reg: float = 0.0,
        roll_grid: int = 0,
    ):
        super().__init__(boom)
        if not 0 < train < samples:
            raise ConfigError(f"rbf: need 0 < train < samples, got train={train}, samples={samples}")
        if roll_grid < 0:
            raise ConfigError(f"rbf.roll_grid = {roll_grid}: must be >= 0")
        self.space = JointSpace(boom, locks)
        self.samples, self.train, self.spread, self.seed, self.name = samples, train, spread, seed, name
        self.spreads, self.reg, self.roll_grid = tuple(spreads), reg, roll_grid
        lo, hi = box if box is not None else (boom.limits()[0], boom.limits()[1])
        self.lo, self.hi = (torch.maximum(lo[self.space.free], self.space.lower),
                            torch.minimum(hi[self.space.free], self.space.upper))
        self.net: ExactRBF | None = None
        self.fit_set: tuple[torch.Tensor, torch.Tensor] | None = None  # (features, free joints)
        self.test_set: tuple[torch.Tensor, torch.Tensor] | None = None
        self.spread_scores: dict[float, float] = {}
        home = torch.zeros(boom.n_joints, dtype=torch.float64)
        self.home_rotation = tool_transform(boom, home)[:3, :3]

    def fit(self) -> RBFSolver:
        g = torch.Generator().manual_seed(self.seed)
        x = self.lo + torch.rand(self.samples, self.space.n, generator=g, dtype=torch.float64) * (self.hi - self.lo)
        feats = frame_features(tool_transform(self.boom, self.space.full(x)), self.home_rotation)
        self.fit_set = feats[: self.train], x[: self.train]
        self.test_set = feats[self.train:], x[self.train:]
        for spread in self.spreads:  # held-out joint error (fraction of the sampled range) per spread
            net = ExactRBF(*self.fit_set, spread, self.reg)
            self.spread_scores[spread] = float(((net(self.test_set[0]) - self.test_set[1]).abs()
                                                / (self.hi - self.lo)).mean())
        if self.spreads:
            self.spread = min(self.spread_scores, key=self.spread_scores.get)
        self.net = ExactRBF(*self.fit_set, self.spread, self.reg)
        return self

    def hole_frames(self, targets: HoleTargets, roll: torch.Tensor | None = None) -> torch.Tensor:
        """Full tool rotations for holes: the home rotation turned onto each hole direction, then
        turned by ``roll`` (rad, per hole) about it."""
        d = targets.pose[:, 3:] - targets.pose[:, :3]
        d = d / d.norm(dim=-1, keepdim=True)
        R = align(self.home_rotation[:, 2], d) @ self.home_rotation
        if roll is not None:
            R = torch.linalg.matrix_exp(roll[:, None, None] * skew(d)) @ R
        return R

    def _answer(self, rotations: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        home = self.home_rotation
        feats = torch.cat([rpy(rotations @ home.transpose(-1, -2)), positions.double()], dim=-1)
        return self.space.full(self.space.clamp(self.net(feats)))  # the interpolant may leave the ranges

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        if self.net is None:
            self.fit()
        once = torch.ones(len(targets), dtype=torch.long)
        if isinstance(targets, FrameTargets):
            return self._answer(targets.rotation.double(), targets.position), once
        if not isinstance(targets, HoleTargets):
            raise InputError(f"{self.name}: unsupported targets {type(targets).__name__}")
        if not self.roll_grid:
            return self._answer(self.hole_frames(targets), targets.pose[:, :3]), once
        B, K = len(targets), self.roll_grid
        rolls = torch.linspace(-math.pi, math.pi, K + 1, dtype=torch.float64)[:-1]
        many = targets.subset(torch.arange(B).repeat_interleave(K))
        q = self._answer(self.hole_frames(many, rolls.repeat(B)), many.pose[:, :3])
        err = many.errors(tool_transform(self.boom, q))["hole"].reshape(B, K)
        pick = err.argmin(dim=1) + torch.arange(B) * K
        return q[pick], torch.full((B,), K, dtype=torch.long)
