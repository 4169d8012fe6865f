"""Batched, differentiable forward kinematics of serial chains given as D-H rows.

A :class:`Boom` is built from a plain mapping (a ``conf/boom/*.yaml`` file) and
evaluates every frame of the chain for any leading batch shape, in the dtype and
on the device of the joint tensor it is given.

Conventions (``convention`` in the config):

* ``modified`` (Craig; paper 000 eq. 1): ``T(i-1,i) = RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(theta_i) TransZ(d_i)``
* ``standard``: ``T(i-1,i) = RotZ(theta_i) TransZ(d_i) TransX(a_i) RotX(alpha_i)``

A joint drives one parameter of one row: ``theta`` (revolute), ``d`` (prismatic)
or ``a`` (a prismatic link extension, as huang9's L1). Its value is added to the
row's offset. Lengths are converted to metres and angles to radians on load.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError, InputError

CONVENTIONS = ("modified", "standard")
JOINT_PARAMS = ("theta", "d", "a")
ROW_KEYS = ("alpha", "a", "theta", "d")
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}
BOOM_KEYS = {
    "name", "convention", "length_unit", "angle_unit", "dh", "joints", "tool",
    "preview_depth", "bodies", "self_pairs", "description",
}
JOINT_KEYS = {"name", "label", "row", "param", "range", "locked"}
BODY_KEYS = {"start", "end", "radius", "tunnel_skip_end"}
POINT_KEYS = {"frame", "along_z"}


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


def _require(mapping: Mapping, key: str, where: str):
    if key not in mapping or mapping[key] is None:
        raise ConfigError(f"{where}: missing required field '{key}'")
    return mapping[key]


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where} = {value!r}: expected a number")
    if not math.isfinite(value):
        raise ConfigError(f"{where} = {value!r}: expected a finite number")
    return float(value)


def _reject_unknown(mapping: Mapping, allowed: set[str], where: str) -> None:
    unknown = sorted(set(mapping) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {unknown}; allowed: {sorted(allowed)}")


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

    # ------------------------------------------------------------------ config
    @classmethod
    def from_config(cls, cfg: Mapping) -> Boom:
        """Build a boom from a ``conf/boom/*.yaml`` mapping, validating every field."""
        if not isinstance(cfg, Mapping):
            raise ConfigError(f"boom config must be a mapping, got {type(cfg).__name__}")
        name = str(cfg.get("name", "<unnamed>"))
        where = f"boom '{name}'"
        _reject_unknown(cfg, BOOM_KEYS, where)
        convention = _require(cfg, "convention", where)
        if convention not in CONVENTIONS:
            raise ConfigError(f"{where}: convention = {convention!r}; expected one of {CONVENTIONS}")
        lu = cfg.get("length_unit", "m")
        au = cfg.get("angle_unit", "deg")
        if lu not in LENGTH_UNITS:
            raise ConfigError(f"{where}: length_unit = {lu!r}; expected one of {sorted(LENGTH_UNITS)}")
        if au not in ANGLE_UNITS:
            raise ConfigError(f"{where}: angle_unit = {au!r}; expected one of {sorted(ANGLE_UNITS)}")
        ls, as_ = LENGTH_UNITS[lu], ANGLE_UNITS[au]

        dh = _require(cfg, "dh", where)
        if not isinstance(dh, Sequence) or isinstance(dh, str) or len(dh) == 0:
            raise ConfigError(f"{where}: dh must be a non-empty list of rows, got {dh!r}")
        rows = []
        for i, row in enumerate(dh, start=1):
            rw = f"{where}: dh row {i}"
            if not isinstance(row, Mapping):
                raise ConfigError(f"{rw} = {row!r}: expected a mapping with {ROW_KEYS}")
            _reject_unknown(row, set(ROW_KEYS), rw)
            vals = {k: _number(_require(row, k, rw), f"{rw}.{k}") for k in ROW_KEYS}
            rows.append((vals["alpha"] * as_, vals["a"] * ls, vals["theta"] * as_, vals["d"] * ls))

        joints_cfg = _require(cfg, "joints", where)
        joints = []
        seen: set[str] = set()
        for j, jc in enumerate(joints_cfg, start=1):
            jw = f"{where}: joint {j}"
            if not isinstance(jc, Mapping):
                raise ConfigError(f"{jw} = {jc!r}: expected a mapping")
            _reject_unknown(jc, JOINT_KEYS, jw)
            jname = str(_require(jc, "name", jw))
            jw = f"{where}: joint '{jname}'"
            if jname in seen:
                raise ConfigError(f"{jw}: duplicate joint name")
            seen.add(jname)
            row = _require(jc, "row", jw)
            if isinstance(row, bool) or not isinstance(row, int) or not 1 <= row <= len(rows):
                raise ConfigError(f"{jw}.row = {row!r}: expected a D-H row number 1..{len(rows)}")
            param = _require(jc, "param", jw)
            if param not in JOINT_PARAMS:
                raise ConfigError(f"{jw}.param = {param!r}; expected one of {JOINT_PARAMS}")
            scale = as_ if param == "theta" else ls
            rng = _require(jc, "range", jw)
            if not isinstance(rng, Sequence) or isinstance(rng, str) or len(rng) != 2:
                raise ConfigError(f"{jw}.range = {rng!r}: expected [lower, upper]")
            lo, hi = (_number(v, f"{jw}.range") * scale for v in rng)
            if not lo < hi:
                raise ConfigError(f"{jw}.range = {list(rng)!r}: lower must be below upper")
            locked = jc.get("locked")
            if locked is not None:
                locked = _number(locked, f"{jw}.locked") * scale
                if not lo <= locked <= hi:
                    raise ConfigError(f"{jw}.locked = {jc['locked']!r} lies outside range {list(rng)!r}")
            joints.append(Joint(jname, row - 1, param, lo, hi, locked, str(jc.get("label", ""))))
        if not joints:
            raise ConfigError(f"{where}: joints must list at least one joint")

        tool = cfg.get("tool", (0.0, 0.0, 0.0))
        if not isinstance(tool, Sequence) or isinstance(tool, str) or len(tool) != 3:
            raise ConfigError(f"{where}: tool = {tool!r}: expected [x, y, z] in the last frame")
        tool = [_number(v, f"{where}: tool") * ls for v in tool]
        depth = cfg.get("preview_depth")
        if depth is not None:
            depth = _number(depth, f"{where}: preview_depth") * ls
            if depth <= 0:
                raise ConfigError(f"{where}: preview_depth = {cfg['preview_depth']!r}: must be > 0")

        n_frames = len(rows) + 2
        bodies = []
        for bname, bc in (cfg.get("bodies") or {}).items():
            bw = f"{where}: bodies.{bname}"
            _reject_unknown(bc, BODY_KEYS, bw)
            ends = []
            for key in ("start", "end"):
                pc = _require(bc, key, bw)
                _reject_unknown(pc, POINT_KEYS, f"{bw}.{key}")
                frame = _require(pc, "frame", f"{bw}.{key}")
                if frame != "tool" and (
                    isinstance(frame, bool) or not isinstance(frame, int) or not 0 <= frame <= len(rows)
                ):
                    raise ConfigError(f"{bw}.{key}.frame = {frame!r}: expected 0..{len(rows)} or 'tool'")
                frame = n_frames - 1 if frame == "tool" else frame
                ends.append(PointSpec(frame, _number(pc.get("along_z", 0.0), f"{bw}.{key}.along_z") * ls))
            radius = _number(_require(bc, "radius", bw), f"{bw}.radius") * ls
            skip = _number(bc.get("tunnel_skip_end", 0.0), f"{bw}.tunnel_skip_end") * ls
            if radius < 0 or skip < 0:
                raise ConfigError(f"{bw}: radius and tunnel_skip_end must be >= 0")
            bodies.append(Capsule(str(bname), ends[0], ends[1], radius, skip))
        names = {b.name for b in bodies}
        pairs = []
        for pair in cfg.get("self_pairs") or []:
            if len(pair) != 2 or not set(pair) <= names:
                raise ConfigError(f"{where}: self_pairs entry {list(pair)!r} must name two bodies of {sorted(names)}")
            pairs.append(tuple(pair))
        return cls(name, convention, rows, joints, tool, depth, bodies, pairs)

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


def pose_errors(pose_hat: torch.Tensor, pose: torch.Tensor) -> dict[str, torch.Tensor]:
    """Spec section 4: start, preview and hole-seeking error (m), direction error (rad)."""
    e_s = torch.linalg.vector_norm(pose_hat[..., :3] - pose[..., :3], dim=-1)
    e_p = torch.linalg.vector_norm(pose_hat[..., 3:] - pose[..., 3:], dim=-1)
    u = pose_hat[..., 3:] - pose_hat[..., :3]
    v = pose[..., 3:] - pose[..., :3]
    # atan2(|u x v|, u.v) stays accurate for the small angles that matter here, unlike arccos.
    angle = torch.atan2(torch.linalg.vector_norm(torch.cross(u, v, dim=-1), dim=-1), (u * v).sum(-1))
    return {"start": e_s, "preview": e_p, "hole": 0.5 * (e_s + e_p), "direction": angle}
