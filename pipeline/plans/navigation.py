"""Navigation: where the rig stands in the plan's frame, and the plan taken into the rig's.

A real plan is drawn in the tunnel's or the mine's coordinates. Before drilling, a rig finds its own pose
in that frame, with a laser or a total station (docs/plans_to_rig.md, "Navigation"). Either

- **given**: ``navigation.pose = [x, y, z, yaw, pitch, roll]`` (metres, degrees): the rig frame's origin at
  (x, y, z) of the plan frame, its axes turned by ``R = Rz(yaw) Ry(pitch) Rx(roll)``; or
- **measured**: ``navigation.points = <file.csv>`` (``point, plan_x, plan_y, plan_z, rig_x, rig_y, rig_z``):
  reference points known in the plan frame and measured from the rig. The pose is the least-squares rigid
  fit ``plan ~ R rig + t`` (no scale), scipy's ``Rotation.align_vectors`` (the Kabsch solution) on the
  centred points. It is refused on fewer than three points, on points that lie too near one line to fix
  the turn about it, and when its rms residual exceeds ``navigation.max_rms_m``, naming the worst point.

A plan point ``p`` is ``R^T (p - t)`` in the rig frame. Joints and trajectories stay in the rig frame;
every point reported back to the plan is taken back into the plan frame (:meth:`RigPose.to_plan`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.core.csv_input import read_text_csv
from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import rule
from pipeline.plans.model import COORDS, MAX_COORD, DrillPlan

POINT_COLUMNS = ["point", "plan_x", "plan_y", "plan_z", "rig_x", "rig_y", "rig_z"]
MAX_POINTS = 1000  # reference points in one file: a survey has a handful


@dataclass(frozen=True)
class NavigationSettings:
    """The ``navigation`` node (conf/navigation/default.yaml)."""

    pose: tuple[float, ...] | None = None
    points: str | None = None
    max_rms_m: float = field(default=0.02, metadata=rule(gt=0))
    min_off_line_m: float = field(default=0.2, metadata=rule(gt=0))

    def __post_init__(self):
        if self.pose is not None and self.points is not None:
            raise ConfigError("navigation: give navigation.pose or navigation.points, not both")
        if self.pose is not None and (len(self.pose) != 6 or not all(math.isfinite(v) for v in self.pose)):
            raise ConfigError(f"navigation.pose = {list(self.pose)!r}: expected [x, y, z, yaw, pitch, roll] "
                              "(six finite numbers: metres, degrees)")


@dataclass(frozen=True)
class RigPose:
    """The rig frame in the plan frame: ``p_plan = R p_rig + t``."""

    R: np.ndarray
    t: np.ndarray
    source: str = "none"  # none | navigation.pose | navigation.points=<file>
    fit: dict | None = None  # the measured pose's residuals (rms_m, max_m, worst_point, residuals_m, points)

    @property
    def is_identity(self) -> bool:
        return bool(np.array_equal(self.R, np.eye(3)) and not self.t.any())

    def to_rig(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3k)`` plan-frame points (x, y, z repeated) in the rig frame."""
        p = np.asarray(points, dtype=np.float64)
        xyz = p.reshape(*p.shape[:-1], -1, 3)
        return ((xyz - self.t) @ self.R).reshape(p.shape)

    def to_plan(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3k)`` rig-frame points in the plan frame."""
        p = np.asarray(points, dtype=np.float64)
        xyz = p.reshape(*p.shape[:-1], -1, 3)
        return (xyz @ self.R.T + self.t).reshape(p.shape)

    def as_pose(self) -> list[float]:
        """``[x, y, z, yaw, pitch, roll]`` (m, deg), the form ``navigation.pose`` takes."""
        from scipy.spatial.transform import Rotation

        yaw, pitch, roll = Rotation.from_matrix(self.R).as_euler("ZYX", degrees=True)
        return [*(float(v) for v in self.t), float(yaw), float(pitch), float(roll)]

    def record(self) -> dict:
        """What a stage's JSON and MLflow run say of the navigation."""
        out = {"source": self.source, "pose": [round(v, 9) for v in self.as_pose()]}
        if self.fit is not None:
            out.update(self.fit)
        return out


IDENTITY = RigPose(np.eye(3), np.zeros(3))


def pose_from_angles(pose) -> RigPose:
    """:class:`RigPose` of ``[x, y, z, yaw, pitch, roll]`` (m, deg): ``R = Rz(yaw) Ry(pitch) Rx(roll)``,
    scipy's intrinsic ``"ZYX"`` sequence."""
    from scipy.spatial.transform import Rotation

    x, y, z, yaw, pitch, roll = (float(v) for v in pose)
    R = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    return RigPose(R, np.array([x, y, z]), "navigation.pose")


def read_points(path: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, plan-frame points ``(n, 3)`` and rig-frame points ``(n, 3)`` of a reference-point file; every
    fault names the file and the row (the header is row 1)."""
    df = read_text_csv(path, "reference-point file (navigation.points)", POINT_COLUMNS)
    if len(df) > MAX_POINTS:
        raise InputError(f"{path}: {len(df)} reference points; at most {MAX_POINTS}")
    names = [str(v).strip() for v in df["point"]]
    values = np.stack([pd.to_numeric(df[c].str.strip(), errors="coerce").to_numpy(float)
                       for c in POINT_COLUMNS[1:]], -1)
    bad = ~np.isfinite(values)
    if bad.any():
        i, j = (int(v[0]) for v in np.nonzero(bad))
        raise InputError(f"{path}: row {i + 2}, point {names[i]!r}, column {POINT_COLUMNS[j + 1]}: "
                         f"{df[POINT_COLUMNS[j + 1]].iloc[i]!r} is not a finite number (m)")
    seen: dict[str, int] = {}
    for i, name in enumerate(names):
        if not name:
            raise InputError(f"{path}: row {i + 2}: a reference point without a name")
        if name in seen:
            raise InputError(f"{path}: row {i + 2}: point {name!r} again (first at row {seen[name] + 2})")
        seen[name] = i
    return names, values[:, :3], values[:, 3:]


def fit_pose(path: str | Path, max_rms_m: float = 0.02, min_off_line_m: float = 0.2) -> RigPose:
    """The least-squares rigid pose of the reference points in ``path`` (module docstring), refused when it
    cannot be trusted."""
    from scipy.spatial.transform import Rotation

    path = Path(path)
    names, plan, rig = read_points(path)
    where = f"navigation.points={path}"
    if len(names) < 3:
        raise InputError(f"{where}: {len(names)} reference point(s); a pose needs at least three not on one line")
    # Points near one line leave the turn about it undetermined: the farthest point off the best line
    # through the measured points must be at least min_off_line_m away.
    centred = rig - rig.mean(axis=0)
    direction = np.linalg.svd(centred, full_matrices=False)[2][0]
    off = np.linalg.norm(centred - np.outer(centred @ direction, direction), axis=1)
    if off.max() < min_off_line_m:
        raise InputError(f"{where}: the points lie on one line (the farthest, {names[int(off.argmax())]!r}, is "
                         f"{off.max():.3f} m from it; navigation.min_off_line_m = {min_off_line_m:g}): the turn "
                         "about that line is not fixed; measure a point off it")
    rotation, _ = Rotation.align_vectors(plan - plan.mean(axis=0), centred)
    R = rotation.as_matrix()
    t = plan.mean(axis=0) - R @ rig.mean(axis=0)
    residual = np.linalg.norm(plan - (rig @ R.T + t), axis=1)
    rms = float(np.sqrt(np.mean(residual**2)))
    worst = int(residual.argmax())
    if rms > max_rms_m:
        raise InputError(f"{where}: the fit's rms residual is {rms:.4f} m, over navigation.max_rms_m = "
                         f"{max_rms_m:g} m; the worst point is {names[worst]!r} ({residual[worst]:.4f} m off): "
                         "check its measurement, or leave it out")
    fit = {"points": len(names), "rms_m": rms, "max_m": float(residual[worst]), "worst_point": names[worst],
           "residuals_m": {n: float(r) for n, r in zip(names, residual, strict=True)}}
    return RigPose(R, t, where, fit)


def rig_pose(settings: NavigationSettings, resolve=Path) -> RigPose:
    """The navigation a stage's settings give: identity, a given pose or a measured one (``resolve`` turns
    a configured path into a file: the stages resolve from the project root)."""
    if settings.pose is not None:
        return pose_from_angles(settings.pose)
    if settings.points is not None:
        return fit_pose(resolve(settings.points), settings.max_rms_m, settings.min_off_line_m)
    return IDENTITY


def in_rig_frame(plan: DrillPlan, pose: RigPose) -> DrillPlan:
    """The plan with its holes in the rig frame (``plan.navigation`` says how; the identity leaves the
    numbers as read). A hole more than :data:`MAX_COORD` from the rig there becomes a bad row naming the
    navigation: far beyond any boom, it is a plan in another frame than the one navigated to."""
    plan.navigation = pose
    if not pose.is_identity:
        holes = plan.holes.copy()
        holes[COORDS] = pose.to_rig(holes[COORDS].to_numpy(dtype=np.float64))
        plan.holes = holes
    xyz = plan.holes[COORDS].to_numpy(dtype=np.float64)
    far = ~(np.abs(xyz) <= MAX_COORD).all(axis=1)
    how = "navigation" if pose.is_identity else pose.source
    plan.drop_rows(far, "navigation", [
        f"{np.abs(xyz[i]).max():.6g} m from the rig in the rig frame ({how}), beyond {MAX_COORD:g} m: "
        + ("a plan in another frame needs navigation.pose or navigation.points" if pose.is_identity else
           "the plan and the navigation are in different frames, or a unit is wrong")
        for i in np.flatnonzero(far)])
    return plan


def navigation_params(plan: DrillPlan) -> dict:
    """MLflow params of the navigation a plan was read with: its source and the pose."""
    pose = plan.navigation or IDENTITY
    return {"navigation": pose.source, "navigation_pose": [round(v, 6) for v in pose.as_pose()]}


def navigation_metrics(plan: DrillPlan) -> dict:
    """MLflow metrics of a measured pose: the fit's rms and largest residual (m), each point's residual."""
    fit = (plan.navigation or IDENTITY).fit
    if fit is None:
        return {}
    return {"navigation_rms_m": fit["rms_m"], "navigation_max_m": fit["max_m"],
            **{f"navigation_residual_m.{re.sub(r'[^A-Za-z0-9_.-]', '_', name)}": r  # MLflow's key alphabet
               for name, r in fit["residuals_m"].items()}}


def same_navigation(pose: RigPose, recorded: dict | None, where) -> None:
    """Refuse to go on from a planned set whose plan was taken into the rig frame another way: its joints
    would drill the plan somewhere else. ``recorded``: the set's JSON ``navigation`` (absent in sets from
    before navigation existed, which were planned in the rig frame)."""
    planned = np.asarray((recorded or {}).get("pose", IDENTITY.as_pose()), dtype=float)
    now = np.asarray(pose.as_pose(), dtype=float)
    if planned.shape != (6,) or not np.allclose(planned, now, rtol=0, atol=1e-6):
        raise ConfigError(f"navigation: {where} was planned with the rig at {planned.round(6).tolist()} "
                          f"([x, y, z, yaw, pitch, roll], {(recorded or {}).get('source', 'none')}), this run puts it "
                          f"at {now.round(6).tolist()} ({pose.source}): give the navigation it was planned with")
