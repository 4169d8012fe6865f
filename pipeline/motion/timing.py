"""How long a boom takes (docs/reference.md, section 7): moves between configurations, and drilling a hole.

A move from A to B is a straight line in joint space, ``q(t) = A + s(t) (B - A)``, with one path
profile ``s`` (0 to 1) for every joint, so all joints start and end together. Joint i's step
``|d_i|`` scales the path's speed and acceleration: ``s`` may move at most at ``V = min_i v_i / |d_i|``
and accelerate at most at ``A = min_i a_i / |d_i|``. The fastest such profile is a trapezoid
(accelerate at A to V, cruise, brake) or, when V is out of reach, a triangle. When every joint
reaches its speed in the same time (the reference's 0.5 s, a_i = v_i / 0.5 s), its duration is exactly
that of the slowest joint alone (:func:`joint_times`), and no joint exceeds its own v_i or a_i.

Full-turn joints (revolute with a range of 360 degrees: q4 and q7 of jumbo8) take the short way
round; their positions along a move are continuous (they may leave [-180, 180] degrees, where the
chain is the same), so that rows of a trajectory interpolate linearly; :func:`wrap` folds them back.

The motion settings are the composed ``motion`` node (``conf/motion/<boom>.yaml`` selected by
``motion=``, ``motion.*`` overrides applied), handed in by the stage: nothing here reads a file. The
node is for booms of one kind (its ``boom`` key): :func:`rig_motions` refuses a rig boom of another kind.

Drilling a hole: collaring, then the hole length at the penetration rate, then the retraction of
the drill steel over the same length (toe back to collar) at the retraction speed; the boom holds
the hole's joints throughout.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError
from pipeline.core.settings import check_rule, coerce, parse, rule
from pipeline.geometry.boom_config import reject_unknown
from pipeline.geometry.kinematics import Boom

MOTION_KEYS = {"boom", "joint_speeds", "accel_time", "drilling"}
# Bounds of the durations (conf/motion/jumbo8.yaml): an hour's collaring or a minute to reach a joint's speed is no
# boom; every hole of a round pays them
MAX_COLLARING_S = 3600.0
MAX_ACCEL_S = 60.0


@dataclass(frozen=True)
class DrillingSettings:
    collaring_s: float = field(default=10.0, metadata=rule(ge=0, le=MAX_COLLARING_S))
    rate_m_per_min: float = field(default=2.5, metadata=rule(gt=0))
    retract_m_per_s: float = field(default=1.0, metadata=rule(gt=0))


@dataclass(frozen=True)
class JointLimits:
    """Per joint of one boom: speed ``v`` (rad/s or m/s), acceleration ``a`` (rad/s^2 or m/s^2) and
    whether it turns fully (``wrap``)."""

    names: tuple[str, ...]
    v: tuple[float, ...]
    a: tuple[float, ...]
    wrap: tuple[bool, ...]

    def tensors(self, dtype=torch.float64, device=None):
        t = lambda x: torch.tensor(x, dtype=dtype, device=device)  # noqa: E731
        return t(self.v), t(self.a), torch.tensor(self.wrap, device=device)


@dataclass(frozen=True)
class MotionModel:
    """A boom's motion settings (the composed ``motion`` node): its joint limits and its drilling."""

    joints: JointLimits
    drilling: DrillingSettings


def full_turn(boom: Boom) -> tuple[bool, ...]:
    """Which joints turn fully: revolute, free, with a range of at least 360 degrees."""
    return tuple(j.revolute and j.locked is None and j.upper - j.lower >= 2 * math.pi - 1e-9 for j in boom.joints)


def motion_from_config(cfg: Mapping, boom: Boom, source: str = "motion") -> MotionModel:
    """The motion node (``source``, the setting's name, prefixes every message: ``motion.accel_time``) for
    ``boom``: ``boom`` (the boom kind it is for; optional), ``joint_speeds`` (deg/s for revolute joints, m/s
    for prismatic ones, one per joint of the boom), ``accel_time`` (s to reach each speed) and ``drilling``."""
    if not isinstance(cfg, Mapping):
        raise ConfigError(f"{source}: expected a mapping, got {cfg!r}")
    reject_unknown(cfg, MOTION_KEYS, source)
    kind = cfg.get("boom")
    if kind is not None and kind != boom.name:
        raise ConfigError(f"{source}.boom = {kind!r}: these motion settings are for booms of kind {kind!r}, not for "
                          f"boom {boom.name!r} (select its motion with motion=<file> of conf/motion/)")
    speeds = cfg.get("joint_speeds")
    if not isinstance(speeds, Mapping):
        raise ConfigError(f"{source}.joint_speeds = {speeds!r}: expected a mapping joint name -> speed")
    missing = [n for n in boom.joint_names if n not in speeds]
    extra = sorted(set(speeds) - set(boom.joint_names))
    if missing or extra:
        raise ConfigError(f"{source}.joint_speeds must list every joint of boom '{boom.name}' "
                          f"{boom.joint_names}; missing {missing}, unknown {extra}")
    accel = coerce(cfg.get("accel_time"), "float", f"{source}.accel_time")
    check_rule(accel, f"{source}.accel_time", gt=0, le=MAX_ACCEL_S)
    v = []
    for j in boom.joints:
        where = f"{source}.joint_speeds.{j.name}"
        value = coerce(speeds[j.name], "float", where)
        check_rule(value, where, gt=0)
        v.append(math.radians(value) if j.revolute else value)
    drilling = parse(DrillingSettings, cfg.get("drilling", {}), f"{source}.drilling")
    limits = JointLimits(tuple(boom.joint_names), tuple(v), tuple(x / accel for x in v), full_turn(boom))
    return MotionModel(limits, drilling)


def rig_motions(cfg: Mapping, booms: Sequence, source: str = "motion") -> list[MotionModel]:
    """One :class:`MotionModel` per boom of a rig (``booms``: its :class:`MountedBoom` s) from the one
    composed ``motion`` node: every boom must be of the node's kind (``motion.boom``); a rig that mixes
    kinds is refused, naming the boom, as one node cannot hold two kinds' speeds."""
    out = []
    for m in booms:
        try:
            out.append(motion_from_config(cfg, m.boom, source))
        except ConfigError as e:
            raise ConfigError(f"rig boom '{m.name}' (a {m.boom.name!r}): {e}") from e
    return out


def joint_steps(qa: torch.Tensor, qb: torch.Tensor, limits: JointLimits) -> torch.Tensor:
    """``qb - qa`` per joint, full-turn joints the short way (in [-pi, pi))."""
    d = qb - qa
    wrap = limits.tensors(d.dtype, d.device)[2]
    return torch.where(wrap, torch.remainder(d + math.pi, 2 * math.pi) - math.pi, d)


def wrap(q: torch.Tensor, limits: JointLimits) -> torch.Tensor:
    """``q`` with full-turn joints folded into [-pi, pi)."""
    return torch.where(limits.tensors(q.dtype, q.device)[2], torch.remainder(q + math.pi, 2 * math.pi) - math.pi, q)


def joint_times(step: torch.Tensor, limits: JointLimits) -> torch.Tensor:
    """Shortest time of each joint alone over ``step`` ``(..., n)``: trapezoid ``|d|/v + v/a`` when it
    reaches ``v`` (``|d| >= v^2/a``), else triangle ``2 sqrt(|d|/a)``."""
    v, a, _ = limits.tensors(step.dtype, step.device)
    d = step.abs()
    return torch.where(d >= v * v / a, d / v + v / a, 2 * torch.sqrt(d / a))


@dataclass(frozen=True)
class Profile:
    """A synchronised move ``q(t) = start + s(t) step`` batched over moves ``(...)``: duration ``T``,
    acceleration phase ``tau``, path acceleration ``accel`` and top path speed ``peak`` (1/s)."""

    start: torch.Tensor  # (..., n)
    step: torch.Tensor  # (..., n), full-turn joints the short way
    duration: torch.Tensor  # (...)
    tau: torch.Tensor
    accel: torch.Tensor
    peak: torch.Tensor

    def path(self, t: torch.Tensor) -> torch.Tensor:
        """``s(t)`` in [0, 1] at times ``t (..., K)`` (clamped to [0, T]): ``(..., K)``."""
        T, tau, A, V = (x.unsqueeze(-1) for x in (self.duration, self.tau, self.accel, self.peak))
        t = torch.minimum(t.clamp_min(0), T)
        rise = 0.5 * A * t * t
        cruise = 0.5 * A * tau * tau + V * (t - tau)
        fall = 1 - 0.5 * A * (T - t) ** 2
        s = torch.where(t < tau, rise, torch.where(t > T - tau, fall, cruise))
        return torch.where(T > 0, s, torch.ones_like(s))  # no move: already at B

    def positions(self, t: torch.Tensor) -> torch.Tensor:
        """Joints ``(..., K, n)`` at times ``t (..., K)`` seconds from the move's start."""
        return self.start.unsqueeze(-2) + self.path(t).unsqueeze(-1) * self.step.unsqueeze(-2)


def profile(qa: torch.Tensor, qb: torch.Tensor, limits: JointLimits) -> Profile:
    """The fastest synchronised straight-line move from ``qa`` to ``qb`` (both ``(..., n)``, broadcast)."""
    qa, qb = torch.broadcast_tensors(qa, qb)
    step = joint_steps(qa, qb, limits)
    v, a, _ = limits.tensors(step.dtype, step.device)
    d = step.abs()
    inf = torch.full_like(d, math.inf)
    V = torch.where(d > 0, v / torch.where(d > 0, d, 1.0), inf).amin(-1)  # path speed limit
    A = torch.where(d > 0, a / torch.where(d > 0, d, 1.0), inf).amin(-1)  # path acceleration limit
    moving = torch.isfinite(V)
    V, A = torch.where(moving, V, 1.0), torch.where(moving, A, 1.0)
    triangle = V * V / A > 1  # top speed out of reach over the unit path
    tau = torch.where(triangle, torch.rsqrt(A), V / A)
    T = torch.where(triangle, 2 * tau, 1 / V + V / A)
    zero = torch.zeros_like(T)
    return Profile(qa, step, torch.where(moving, T, zero), torch.where(moving, tau, zero), A,
                   torch.where(triangle, A * tau, V))


def move_time(qa: torch.Tensor, qb: torch.Tensor, limits: JointLimits) -> torch.Tensor:
    """Seconds ``(...)`` of the synchronised move from ``qa`` to ``qb``."""
    return profile(qa, qb, limits).duration


def drilling_time(length: torch.Tensor | float, drilling: DrillingSettings):
    """Seconds to drill holes of ``length`` (m, collar to toe): collaring, penetration over the length,
    retraction over the length."""
    return drilling.collaring_s + length * (60.0 / drilling.rate_m_per_min) + length / drilling.retract_m_per_s
