"""Batched, differentiable forward kinematics of serial chains given as D-H rows.

A :class:`Boom` (read from a ``conf/boom/*.yaml`` file by :mod:`pipeline.geometry.boom_config`)
evaluates every frame of the chain for any leading batch shape, in the dtype and on the device of
the joint tensor it is given, and the geometric Jacobian of any frame-fixed point from those frames.

Conventions (``convention`` in the config):

* ``modified`` (Craig; paper 000 eq. 1): ``T(i-1,i) = RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)``
* ``standard``: ``T(i-1,i) = RotZ(theta_i) TransZ(d_i) TransX(a_i) RotX(alpha_i)``

A joint drives one parameter of one row: ``theta`` (revolute), ``d`` (prismatic)
or ``a`` (a prismatic link extension, as huang9's L1). Its value is added to the
row's offset. Lengths are in metres and angles in radians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.rotations import angle_between

CONVENTIONS = ("modified", "standard")
JOINT_PARAMS = ("theta", "d", "a")


@dataclass(frozen=True)
class Joint:
    """One actuated joint; limits and lock value are in rad (theta) or m (d, a)."""

    name: str
    row: int  # 0-based D-H row it drives
    param: str  # "theta", "d" or "a"
    lower: float
    upper: float
    locked: float | None = None
    label: str = ""

    @property
    def revolute(self) -> bool:
        return self.param == "theta"


@dataclass(frozen=True)
class PointSpec:
    """A point fixed to a frame: its origin plus ``along_z`` metres along its z axis.

    ``frame`` indexes :meth:`Boom.frames`: 0 is the base, k the frame after row k,
    ``n_rows + 1`` the tool frame (``"tool"`` in the config).
    """

    frame: int
    along_z: float = 0.0


@dataclass(frozen=True)
class Capsule:
    """A collision body: the segment start-end inflated by ``radius``.

    The last ``tunnel_skip_end`` metres before ``end`` are not checked against the
    tunnel (the front of the feed beam works at the face).
    """

    name: str
    start: PointSpec
    end: PointSpec
    radius: float
    tunnel_skip_end: float = 0.0


class Boom:
    """A serial chain with joint limits, a tool point and collision capsules."""

    def __init__(
        self,
        name: str,
        convention: str,
        rows: Sequence[tuple[float, float, float, float]],
        joints: Sequence[Joint],
        tool: Sequence[float] = (0.0, 0.0, 0.0),
        preview_depth: float | None = None,
        bodies: Sequence[Capsule] = (),
        self_pairs: Sequence[tuple[str, str]] = (),
    ):
        if convention not in CONVENTIONS:
            raise ConfigError(f"boom '{name}': convention = {convention!r}; expected one of {CONVENTIONS}")
        self.name = name
        self.convention = convention
        self.rows = tuple(tuple(float(v) for v in r) for r in rows)  # (alpha, a, theta, d), rad/m
        self.joints = tuple(joints)
        self.tool = tuple(float(v) for v in tool)
        self.preview_depth = preview_depth
        self.bodies = {b.name: b for b in bodies}
        self.self_pairs = tuple(tuple(p) for p in self_pairs)
        self._cache: dict[tuple, dict[str, torch.Tensor]] = {}

    # ------------------------------------------------------------------ facts
    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def n_rows(self) -> int:
        return len(self.rows)

    @property
    def tool_index(self) -> int:
        """Index of the tool frame in :meth:`frames`."""
        return self.n_rows + 1

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def limits(self, dtype=torch.float64, device=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper joint limits as tensors (locked joints: both equal the lock)."""
        c = self._constants(dtype, torch.device(device) if device is not None else torch.device("cpu"))
        return c["lower"], c["upper"]

    def _constants(self, dtype, device) -> dict[str, torch.Tensor]:
        key = (dtype, device)
        if key not in self._cache:
            t = lambda x: torch.tensor(x, dtype=dtype, device=device)  # noqa: E731
            rows = t(self.rows)
            sel = {p: torch.zeros(self.n_joints, self.n_rows, dtype=dtype, device=device) for p in JOINT_PARAMS}
            for j, joint in enumerate(self.joints):
                sel[joint.param][j, joint.row] = 1.0
            lower = [j.locked if j.locked is not None else j.lower for j in self.joints]
            upper = [j.locked if j.locked is not None else j.upper for j in self.joints]
            self._cache[key] = {
                "cos_alpha": torch.cos(rows[:, 0]),
                "sin_alpha": torch.sin(rows[:, 0]),
                "a": rows[:, 1],
                "theta": rows[:, 2],
                "d": rows[:, 3],
                "sel_theta": sel["theta"],
                "sel_d": sel["d"],
                "sel_a": sel["a"],
                "tool": t(self.tool),
                "lower": t(lower),
                "upper": t(upper),
            }
        return self._cache[key]

    # ------------------------------------------------------------------ checks
    def check_joints(self, q: torch.Tensor, where: str = "q") -> torch.Tensor:
        """Raise :class:`InputError` unless ``q`` is a floating tensor ``(..., n_joints)``."""
        if not isinstance(q, torch.Tensor):
            raise InputError(f"{where}: expected a torch.Tensor of joints, got {type(q).__name__}")
        if not q.is_floating_point():
            raise InputError(f"{where}: expected a floating-point tensor, got dtype {q.dtype}")
        if q.ndim == 0 or q.shape[-1] != self.n_joints:
            got = "a scalar" if q.ndim == 0 else f"length {q.shape[-1]} (shape {tuple(q.shape)})"
            raise InputError(
                f"{where}: joint vector has {got}; boom '{self.name}' has {self.n_joints} joints {self.joint_names}"
            )
        return q

    def within_limits(self, q: torch.Tensor, tol: float = 1e-9) -> torch.Tensor:
        """Boolean ``(...,)``: every joint inside its range (locked joints at their lock)."""
        lo, hi = self.limits(q.dtype, q.device)
        return ((q >= lo - tol) & (q <= hi + tol)).all(dim=-1)

    def with_locks(self, q: torch.Tensor) -> torch.Tensor:
        """``q`` with each locked joint set to its lock value."""
        locked = [(i, j.locked) for i, j in enumerate(self.joints) if j.locked is not None]
        if not locked:
            return q
        q = q.clone()
        for i, v in locked:
            q[..., i] = v
        return q

    # ------------------------------------------------------------------ kinematics
    def link_transforms(self, q: torch.Tensor) -> torch.Tensor:
        """Per-row transforms ``T(i-1, i)``: shape ``(..., n_rows, 4, 4)``."""
        self.check_joints(q)
        c = self._constants(q.dtype, q.device)
        theta = c["theta"] + q @ c["sel_theta"]
        d = c["d"] + q @ c["sel_d"]
        a = c["a"] + q @ c["sel_a"]
        ct, st = torch.cos(theta), torch.sin(theta)
        ca, sa = c["cos_alpha"].expand_as(ct), c["sin_alpha"].expand_as(ct)
        zero, one = torch.zeros_like(ct), torch.ones_like(ct)
        if self.convention == "modified":
            entries = [
                ct, -st, zero, a,
                st * ca, ct * ca, -sa, -d * sa,
                st * sa, ct * sa, ca, d * ca,
                zero, zero, zero, one,
            ]
        else:
            entries = [
                ct, -st * ca, st * sa, a * ct,
                st, ct * ca, -ct * sa, a * st,
                zero, sa, ca, d,
                zero, zero, zero, one,
            ]
        return torch.stack(entries, dim=-1).reshape(*ct.shape, 4, 4)

    def frames(self, q: torch.Tensor) -> torch.Tensor:
        """Every frame in the base frame: ``(..., n_rows + 2, 4, 4)``.

        Index 0 is the base (identity), index k the frame after D-H row k, and the
        last index (:attr:`tool_index`) the tool frame: frame n translated by ``tool``.
        """
        links = self.link_transforms(q)
        eye = torch.eye(4, dtype=q.dtype, device=q.device).expand(*q.shape[:-1], 4, 4)
        out = [eye]
        for i in range(self.n_rows):  # loop over the chain's rows, batched over configurations
            out.append(out[-1] @ links[..., i, :, :])
        last = out[-1]
        tool = self._constants(q.dtype, q.device)["tool"]
        tool_frame = torch.cat(
            [
                torch.cat([last[..., :3, :3], (last[..., :3, :3] @ tool + last[..., :3, 3]).unsqueeze(-1)], dim=-1),
                last[..., 3:, :],
            ],
            dim=-2,
        )
        out.append(tool_frame)
        return torch.stack(out, dim=-3)

    def tool_pose(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Tool point ``p`` and drilling direction ``z`` (unit), each ``(..., 3)``."""
        return self.tool_pose_from_frames(self.frames(q))

    def tool_pose_from_frames(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        tool = frames[..., self.tool_index, :, :]
        return tool[..., :3, 3], tool[..., :3, 2]

    def pose6(self, q: torch.Tensor, depth: float | None = None) -> torch.Tensor:
        """The 6-D hole pose ``[p, p + D z]`` (paper 000 eqs. 3-4): ``(..., 6)``."""
        return self.pose6_from_frames(self.frames(q), depth)

    def pose6_from_frames(self, frames: torch.Tensor, depth: float | None = None) -> torch.Tensor:
        depth = self.preview_depth if depth is None else depth
        if depth is None:
            raise ConfigError(f"boom '{self.name}': preview_depth is not set, so pose6 is undefined")
        p, z = self.tool_pose_from_frames(frames)
        return torch.cat([p, p + depth * z], dim=-1)

    def point(self, frames: torch.Tensor, spec: PointSpec) -> torch.Tensor:
        """Position ``(..., 3)`` of a frame-fixed point."""
        f = frames[..., spec.frame, :3, :]
        return f[..., 3] + spec.along_z * f[..., 2] if spec.along_z else f[..., 3]

    def capsule_ends(self, frames: torch.Tensor, name: str) -> tuple[torch.Tensor, torch.Tensor]:
        body = self.bodies[name]
        return self.point(frames, body.start), self.point(frames, body.end)


    # ------------------------------------------------------------------ Jacobians
    def _axis_layout(self, device) -> dict[str, torch.Tensor]:
        """Per joint, where its axis lives and what it moves (cached per device).

        ``frame``: index in :meth:`frames` of the frame holding the axis. Modified D-H
        (``RotX(alpha) TransX(a) RotZ(theta) TransZ(d)``): theta and d act along z of the frame after
        the row, ``a`` along x of the frame before it. Standard D-H (``RotZ(theta) TransZ(d)
        TransX(a) RotX(alpha)``): theta and d act along z of the frame before the row, ``a`` along x of
        the frame after it. ``along_x``: the axis is that frame's x. ``moves``: the first frame index
        the joint moves (every frame after its row, in both conventions)."""
        key = ("axes", device)
        if key not in self._cache:
            frame = [j.row if (j.param == "a") == (self.convention == "modified") else j.row + 1 for j in self.joints]
            self._cache[key] = {
                "frame": torch.tensor(frame, device=device),
                "along_x": torch.tensor([j.param == "a" for j in self.joints], device=device).unsqueeze(-1),
                "revolute": torch.tensor([j.revolute for j in self.joints], device=device).unsqueeze(-1),
                "moves": torch.tensor([j.row + 1 for j in self.joints], device=device),
            }
        return self._cache[key]

    def joint_axes(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Unit axis ``(..., n_joints, 3)`` of each joint and a point ``(..., n_joints, 3)`` on it."""
        layout = self._axis_layout(frames.device)
        F = frames[..., layout["frame"], :3, :]
        return torch.where(layout["along_x"], F[..., 0], F[..., 2]), F[..., 3]

    def point_jacobian(
        self, frames: torch.Tensor, point: torch.Tensor, frame: int | None = None, axes=None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Geometric Jacobian of a point ``(..., 3)`` fixed to frame index ``frame`` (default: the
        tool frame): linear ``(..., 3, n_joints)`` (revolute column ``u x (p - o)``, prismatic column
        ``u``) and angular (``u`` or 0); columns of joints that do not move that frame are zero.
        From one forward pass, no autograd, so it serves inside solvers' inner loops; pass
        ``axes=self.joint_axes(frames)`` to share them between points."""
        layout = self._axis_layout(frames.device)
        axis, origin = self.joint_axes(frames) if axes is None else axes
        swept = torch.linalg.cross(axis, point.unsqueeze(-2) - origin, dim=-1)
        linear = torch.where(layout["revolute"], swept, axis)
        angular = torch.where(layout["revolute"], axis, torch.zeros_like(axis))
        if frame is not None and frame < self.tool_index:
            moving = (layout["moves"] <= frame).unsqueeze(-1)
            linear, angular = linear * moving, angular * moving
        return linear.transpose(-1, -2), angular.transpose(-1, -2)

    def points_jacobian(self, frames: torch.Tensor, points: torch.Tensor, frame_index: torch.Tensor, axes=None):
        """Linear Jacobians ``(..., E, 3, n_joints)`` of points ``(..., E, 3)``, point ``e`` fixed to
        frame ``frame_index[e]`` (one call for every capsule end of a boom)."""
        layout = self._axis_layout(frames.device)
        axis, origin = self.joint_axes(frames) if axes is None else axes
        axis, origin = axis.unsqueeze(-3), origin.unsqueeze(-3)  # (..., 1, n, 3)
        swept = torch.linalg.cross(axis.expand(*points.shape[:-1], -1, 3), points.unsqueeze(-2) - origin, dim=-1)
        linear = torch.where(layout["revolute"], swept, axis)
        moving = (layout["moves"] <= frame_index.to(layout["moves"].device).unsqueeze(-1)).unsqueeze(-1)
        return (linear * moving).transpose(-1, -2)

    def pose6_jacobian(self, frames: torch.Tensor, depth: float | None = None, axes=None) -> torch.Tensor:
        """``d pose6 / d q``: ``(..., 6, n_joints)``, the collar rows then the preview rows
        (``p' = p + D z``, so its rows add ``D (w x z)``)."""
        depth = self.preview_depth if depth is None else depth
        p, z = self.tool_pose_from_frames(frames)
        linear, angular = self.point_jacobian(frames, p, axes=axes)
        turn = torch.linalg.cross(angular, z.unsqueeze(-1).expand_as(angular), dim=-2)
        return torch.cat([linear, linear + depth * turn], dim=-2)


def pose_errors(pose_hat: torch.Tensor, pose: torch.Tensor) -> dict[str, torch.Tensor]:
    """Spec section 4: start, preview and hole-seeking error (m), direction error (rad)."""
    e_s = torch.linalg.vector_norm(pose_hat[..., :3] - pose[..., :3], dim=-1)
    e_p = torch.linalg.vector_norm(pose_hat[..., 3:] - pose[..., 3:], dim=-1)
    u = pose_hat[..., 3:] - pose_hat[..., :3]
    v = pose[..., 3:] - pose[..., :3]
    return {"start": e_s, "preview": e_p, "hole": 0.5 * (e_s + e_p), "direction": angle_between(u, v)}
