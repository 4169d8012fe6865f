"""Where the rig stands in the plan's frame (the ``navigation`` node), with the checker's own numpy.

At most one of ``navigation.pose`` and ``navigation.points``; neither: the plan is in the rig frame.

``pose = [x, y, z, yaw, pitch, roll]`` (m, deg): the rig frame's origin sits at (x, y, z) of the plan
frame and its axes are turned by ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (right-handed rotations about the
plan's z, y, x axes, in that product order); a plan point p is ``R^T (p - t)`` in the rig frame.

``points = <file.csv>`` (columns ``point, plan_x, plan_y, plan_z, rig_x, rig_y, rig_z``; a relative path
from the project root): the same reference points in the plan frame and measured from the rig. The
pose is the least-squares rigid fit ``plan ~ R rig + t`` (no scale), by the SVD of the centred points'
cross-covariance with the reflection fixed (Kabsch). Refused (:class:`InputError`): fewer than three
points, points on one line (every measured point within ``navigation.min_off_line_m`` of one line: the
rotation about that line is not fixed by them; the stage's own rule), or an rms residual above
``navigation.max_rms_m`` (naming the worst point).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError

POINT_COLUMNS = ["point", "plan_x", "plan_y", "plan_z", "rig_x", "rig_y", "rig_z"]


def rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)``, angles in degrees."""
    cy, sy = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    cp, sp = math.cos(math.radians(pitch)), math.sin(math.radians(pitch))
    cr, sr = math.cos(math.radians(roll)), math.sin(math.radians(roll))
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def angles(R: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees with ``rotation(*angles(R)) == R`` (pitch in [-90, 90])."""
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    return math.degrees(yaw), math.degrees(pitch), math.degrees(roll)


def fit(rig: np.ndarray, plan: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R and translation t minimising ``sum |R rig_i + t - plan_i|^2`` (``(n, 3)`` each)."""
    rc, pc = rig.mean(0), plan.mean(0)
    H = (rig - rc).T @ (plan - pc)
    U, _, Vt = np.linalg.svd(H)
    flip = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0  # a reflection is the best orthogonal fit: take R instead
    R = Vt.T @ np.diag([1.0, 1.0, flip]) @ U.T
    return R, pc - R @ rc


def off_line(p: np.ndarray) -> float:
    """The largest distance of the points ``(n, 3)`` from their least-squares line."""
    c = p - p.mean(0)
    axis = np.linalg.svd(c, full_matrices=False)[2][0]
    return float(np.linalg.norm(c - np.outer(c @ axis, axis), axis=1).max())


@dataclass
class Navigation:
    """``plan = R rig + t``; :meth:`to_rig` takes plan points into the rig frame."""

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    doc: dict = field(default_factory=lambda: {"given": None, "frame": "the plan is in the rig frame"})

    def to_rig(self, p: np.ndarray) -> np.ndarray:
        """``R^T (p - t)`` for points ``(..., 3)`` (NaN rows stay NaN)."""
        return (np.asarray(p, float) - self.t) @ self.R

    def pose(self) -> list[float]:
        return [*(float(v) for v in self.t), *angles(self.R)]


def _finite(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def read_navigation(node, root: Path) -> Navigation:
    """The navigation node (``root``: the project root, for a relative points file)."""
    node = node or {}
    if not isinstance(node, dict):
        raise InputError(f"settings: navigation = {node!r}: expected a mapping with pose, points, max_rms_m")
    pose, points, limit = node.get("pose"), node.get("points"), node.get("max_rms_m")
    if not _finite(limit) or limit <= 0:
        raise InputError(f"settings: navigation.max_rms_m = {limit!r}: expected a positive number")
    spread = node.get("min_off_line_m", 0.2)
    if not _finite(spread) or spread <= 0:
        raise InputError(f"settings: navigation.min_off_line_m = {spread!r}: expected a positive number")
    if pose is not None and points is not None:
        raise InputError(f"settings: navigation.pose = {pose!r} and navigation.points = {points!r}: give at most one")
    if pose is not None:
        if not isinstance(pose, (list, tuple)) or len(pose) != 6 or not all(_finite(v) for v in pose):
            raise InputError(f"settings: navigation.pose = {pose!r}: expected [x, y, z, yaw, pitch, roll] "
                             "(6 finite numbers: m, deg)")
        pose = [float(v) for v in pose]
        return Navigation(rotation(*pose[3:]), np.array(pose[:3]), {"given": "pose", "pose": pose})
    if points is not None:
        return _from_points(points, float(limit), float(spread), root)
    return Navigation()


def _from_points(value, limit: float, min_off_line: float, root: Path) -> Navigation:
    from .files import _numbers, _require, _table

    if not isinstance(value, str) or not value:
        raise InputError(f"settings: navigation.points = {value!r}: expected the path of a points CSV")
    path = Path(value) if Path(value).is_absolute() else root / value
    where = f"navigation.points {path}"
    df = _table(path, "navigation points file (navigation.points)")
    try:
        _require(df, POINT_COLUMNS, path)
        xyz = _numbers(df, POINT_COLUMNS[1:], path)
    except InputError as e:
        raise InputError(f"navigation.points {e}") from None
    names = df["point"].str.strip().tolist()
    n = len(names)
    if n < 3:
        raise InputError(f"{where}: {n} point(s); the rigid fit needs at least three, not on one line")
    plan, rig = xyz[:, :3], xyz[:, 3:]
    # the stage's rule, so that a pose it accepted is one the checker can judge: the measured points must
    # not all lie within navigation.min_off_line_m of one line
    spread = off_line(rig)
    if spread < min_off_line:
        raise InputError(f"{where}: the {n} points (rows 2-{n + 1}) lie on one line as measured (every point within "
                         f"{spread:.3g} m of it, navigation.min_off_line_m = {min_off_line:g} m): the rotation "
                         "about that line is not fixed by them; measure a point off that line")
    R, t = fit(rig, plan)
    res = np.linalg.norm(rig @ R.T + t - plan, axis=1)
    rms = float(np.sqrt(np.mean(res ** 2)))
    w = int(res.argmax())
    if rms > limit:
        raise InputError(f"{where}: the rigid fit's rms residual {rms:.4g} m exceeds navigation.max_rms_m = "
                         f"{limit:g} m; worst point {names[w]!r} (row {w + 2}), {res[w]:.4g} m off")
    nav = Navigation(R, t)
    nav.doc = {"given": "points", "points": str(path), "n": n, "rms_m": rms, "worst_point": names[w],
               "worst_residual_m": float(res[w]), "max_rms_m": limit, "pose": nav.pose()}
    return nav
