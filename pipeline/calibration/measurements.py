"""Measurements of a real (or simulated true) boom: joint vectors with the measured collar point
and drilling direction, as a total station or a laser tracker gives them.

Simulated measurements add seeded Gaussian noise: each collar coordinate gets ``position_mm``
(standard deviation), and the direction is tilted by ``direction_deg`` per axis perpendicular to it.
A field engineer's own file is a CSV with columns ``q1..qn`` (the boom's joint names),
``collar_x/y/z`` and ``dir_x/y/z``; every problem is reported with the file, row and column.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.kinematics import Boom

DTYPE = torch.float64
# unit name -> SI factor (the boom configs use the same names)
ANGLE_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
COLLAR_COLUMNS = ["collar_x", "collar_y", "collar_z"]
DIRECTION_COLUMNS = ["dir_x", "dir_y", "dir_z"]


@dataclass(frozen=True)
class Sensor:
    """Measurement noise (1 sigma): collar per coordinate (mm), direction per tilt axis (deg)."""

    position_mm: float = 1.0  # a total station on a prism at the drill end
    direction_deg: float = 0.05

    def __post_init__(self):
        for key in ("position_mm", "direction_deg"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"calibration sensor.{key} = {v!r}: expected a finite number >= 0")


@dataclass(frozen=True)
class Measurements:
    """``q (N, n_joints)`` (rad / m), ``collar (N, 3)`` (m, base frame), ``direction (N, 3)`` (unit)."""

    q: torch.Tensor
    collar: torch.Tensor
    direction: torch.Tensor
    source: str = "measurements"

    def __len__(self) -> int:
        return self.q.shape[0]

    def subset(self, index) -> Measurements:
        return Measurements(self.q[index], self.collar[index], self.direction[index], self.source)

    def pose6(self, depth: float) -> torch.Tensor:
        """The measured hole pose ``[p, p + D z]`` (paper 000 eq. 4), as IK solvers take it."""
        return torch.cat([self.collar, self.collar + depth * self.direction], dim=-1)


def simulate(boom: Boom, q: torch.Tensor, sensor: Sensor, seed: int) -> Measurements:
    """Collar and direction of ``boom`` (the true one) at ``q``, with the sensor's noise."""
    q = boom.check_joints(q, "measurement joints").to(DTYPE)
    with torch.no_grad():
        p, z = boom.tool_pose(q)
    g = torch.Generator().manual_seed(int(seed))
    p = p + sensor.position_mm * 1e-3 * torch.randn(p.shape, generator=g, dtype=DTYPE)
    # isotropic tilt: a normal vector in the plane perpendicular to z, one sigma per axis
    n = torch.randn(z.shape, generator=g, dtype=DTYPE)
    n = n - (n * z).sum(-1, keepdim=True) * z
    z = z + math.radians(sensor.direction_deg) * n
    return Measurements(q.clone(), p, z / z.norm(dim=-1, keepdim=True), "simulated")


def _joint_columns(columns: list[str]) -> list[str]:
    return [c for c in columns if re.fullmatch(r"q\d+", str(c))]


def read_measurements(path: str | Path, boom: Boom, angle_unit: str = "rad", length_unit: str = "m",
                      range_tolerance: float = 0.01) -> Measurements:
    """Read a field measurement CSV (one row per measured pose) for ``boom``.

    Joints are in ``angle_unit`` (revolute) and ``length_unit`` (prismatic), the collar in
    ``length_unit``; the direction need not be unit length (it is normalised) but must not be zero.
    A joint more than ``range_tolerance`` of its range outside the range is refused: it is almost
    always a unit mix-up (degrees read as radians).
    """
    path = Path(path)
    if angle_unit not in ANGLE_UNITS:
        raise ConfigError(f"calibration.file_units.angle = {angle_unit!r}; expected one of {sorted(ANGLE_UNITS)}")
    if length_unit not in LENGTH_UNITS:
        raise ConfigError(f"calibration.file_units.length = {length_unit!r}; expected one of {sorted(LENGTH_UNITS)}")
    if not path.is_file():
        raise InputError(f"{path}: no such measurement file")
    try:
        df = pd.read_csv(path, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable CSV file ({exc})") from None
    df.columns = [str(c).strip() for c in df.columns]
    names = boom.joint_names
    given = _joint_columns(list(df.columns))
    if given and set(given) != set(names):
        raise InputError(
            f"{path}: joint columns {given} do not match boom '{boom.name}', which has {len(names)} joints {names}"
        )
    columns = names + COLLAR_COLUMNS + DIRECTION_COLUMNS
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing}; expected {columns}, found {list(df.columns)}")
    if len(df) == 0:
        raise InputError(f"{path}: no measurement rows")
    values = {}
    for col in columns:
        v = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            r = int(bad[0])
            raw = df[col].iloc[r]
            shown = repr(raw) if isinstance(raw, str) else str(raw)  # 'abc', nan, inf (not np.float64(nan))
            raise InputError(
                f"{path}: row {r + 1} (line {r + 2}), column '{col}': value {shown} is not a finite "
                f"number ({bad.size} such row(s) in that column)"
            )
        values[col] = v
    a_s, l_s = ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit]
    q = torch.tensor(np.stack([values[j.name] * (a_s if j.revolute else l_s) for j in boom.joints], -1), dtype=DTYPE)
    lo, hi = boom.limits(DTYPE)
    slack = range_tolerance * (hi - lo)
    outside = (q < lo - slack) | (q > hi + slack)
    if outside.any():
        r, j = (int(i) for i in outside.nonzero()[0])
        joint = boom.joints[j]
        unit = angle_unit if joint.revolute else length_unit
        scale = a_s if joint.revolute else l_s
        value = float(values[joint.name][r])
        raise InputError(
            f"{path}: row {r + 1} (line {r + 2}), column '{joint.name}': {value:.6g} {unit} lies "
            f"outside the joint range [{float(lo[j]) / scale:.4g}, {float(hi[j]) / scale:.4g}] {unit}; check "
            "calibration.file_units"
        )
    collar = torch.tensor(np.stack([values[c] for c in COLLAR_COLUMNS], -1), dtype=DTYPE) * l_s
    direction = torch.tensor(np.stack([values[c] for c in DIRECTION_COLUMNS], -1), dtype=DTYPE)
    norm = direction.norm(dim=-1)
    if (norm < 1e-9).any():
        r = int((norm < 1e-9).nonzero()[0])
        raise InputError(f"{path}: row {r + 1} (line {r + 2}): direction (dir_x, dir_y, dir_z) is zero; "
                         "it must point along the drill")
    return Measurements(q, collar, direction / norm.unsqueeze(-1), str(path))


def write_measurements(meas: Measurements, boom: Boom, path: str | Path) -> None:
    """The CSV layout :func:`read_measurements` reads (SI units), e.g. to hand simulated data over."""
    from pipeline.core.io import write_csv

    arr = torch.cat([meas.q, meas.collar, meas.direction], -1).cpu().numpy()
    write_csv(pd.DataFrame(arr, columns=boom.joint_names + COLLAR_COLUMNS + DIRECTION_COLUMNS), path)
