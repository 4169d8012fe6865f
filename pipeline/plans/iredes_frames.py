"""From an IREDES file's points to the boom base frame: the file's ``IR:TMatrix``, then :class:`AxisMap`.

A point ``p`` as the file writes it goes, in this order:

1. ``local_to_plan`` (the file's ``DrillPosPlan/PositionData/Coordsystem/IR:TMatrix``, when it has
   one): its four ``IR:Col`` elements, each ``IR:x, IR:y, IR:z, IR:w``, are the *columns* of a 4x4
   matrix M, and ``p_plan = M[:3, :3] @ p + M[:3, 3]``, in the file's unit (rig software places a
   plan drawn in a local frame into mine coordinates so). No TMatrix: ``p_plan = p``.
2. :class:`AxisMap` (``solve.iredes.axes``, ``unit``, ``origin``): ``base = R @ (scale * (p_plan - origin))``,
   so ``origin`` is the boom base frame's origin in the TMatrix's target coordinates (mine coordinates).

M must place the plan rigidly: four ``Col`` of four finite numbers, last row ``(0, 0, 0, 1)``, and a
3x3 part that is a rotation (``R^T R = I`` within ``tol`` and ``det R > 0``). A scale or shear would
change the holes' lengths and angles and a reflection would mirror the plan, so such a matrix is
refused, naming its line. ``tol`` (``solve.iredes.tmatrix_tol``, 1e-6) can be raised for a file that
writes a rotation's entries with few decimals (three decimals leave ~1e-4); the matrix is then
applied as written, and the solution JSON records it. An empty ``TMatrix`` (nothing but a comment)
is the identity, logged. Several ``TMatrix`` elements are refused unless they are equal.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from xml.etree import ElementTree as ET

import numpy as np

from pipeline.core.errors import ConfigError, InputError

log = logging.getLogger("pipeline.plans.iredes")

UNITS = {"m": 1.0, "mm": 1e-3}
TMATRIX_TOL = 1e-6  # |R^T R - I| and |last row - (0, 0, 0, 1)|: float noise of a computed rotation, no more
_COL_AXES = ("x", "y", "z", "w")


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


# ---------------------------------------------------------------------------------------------
# Axes


@dataclass(frozen=True)
class AxisMap:
    """IREDES points to the boom base frame: ``base = R @ (scale * (point - origin))``.

    ``axes``: for PointX, PointY, PointZ in turn, the base axis it becomes, optionally signed:
    ``"xyz"`` (default) keeps them, ``"yxz"`` swaps the first two (a surface-mine file with
    northing in PointX, read with y along the northing), ``"x-yz"`` flips y. ``unit``: the
    file's length unit, ``"m"`` or ``"mm"``. ``origin``: the base frame's origin as an IREDES
    point, in the file's unit and axes (after the file's TMatrix, when it has one).
    """

    axes: str = "xyz"
    unit: str = "m"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    R: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        spec = str(self.axes).replace(" ", "").lower()
        tokens = re.findall(r"([+-]?)([xyz])", spec)
        if "".join(s + a for s, a in tokens) != spec or sorted(a for _, a in tokens) != ["x", "y", "z"]:
            raise ConfigError(
                f"iredes.axes = {self.axes!r}: expected the base axes of PointX, PointY, PointZ, each of x, y, z "
                f"once with an optional sign, e.g. 'xyz', 'yxz', 'x-yz'"
            )
        if self.unit not in UNITS:
            raise ConfigError(f"iredes.unit = {self.unit!r}: expected one of {list(UNITS)}")
        origin = tuple(self.origin)
        if len(origin) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in origin):
            raise ConfigError(f"iredes.origin = {self.origin!r}: expected three finite numbers (file units)")
        R = np.zeros((3, 3))
        for i, (sign, axis) in enumerate(tokens):
            R["xyz".index(axis), i] = -1.0 if sign == "-" else 1.0
        object.__setattr__(self, "origin", tuple(float(v) for v in origin))
        object.__setattr__(self, "R", R)

    @classmethod
    def from_config(cls, cfg: Mapping | None) -> AxisMap:
        """From a mapping with any of ``axes``, ``unit``, ``origin`` (e.g. a Hydra node)."""
        cfg = dict(cfg or {})
        unknown = sorted(set(cfg) - {"axes", "unit", "origin"})
        if unknown:
            raise ConfigError(f"iredes: unknown field(s) {unknown}; allowed: ['axes', 'unit', 'origin']")
        return cls(**cfg)

    @property
    def scale(self) -> float:
        return UNITS[self.unit]

    def to_base(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3k)`` file points (x, y, z repeated) to base-frame metres."""
        p = np.asarray(points, dtype=np.float64)
        xyz = p.reshape(*p.shape[:-1], -1, 3)
        return (self.scale * (xyz - np.asarray(self.origin)) @ self.R.T).reshape(p.shape)

    def from_base(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        xyz = p.reshape(*p.shape[:-1], -1, 3)
        return ((xyz @ self.R) / self.scale + np.asarray(self.origin)).reshape(p.shape)


def axis_map(axes: str | AxisMap, unit: str, origin) -> AxisMap:
    return axes if isinstance(axes, AxisMap) else AxisMap(axes, unit, tuple(origin))


# ---------------------------------------------------------------------------------------------
# The file's TMatrix


def apply_local_to_plan(M: np.ndarray | None, points: np.ndarray) -> np.ndarray:
    """``(..., 3k)`` file points to plan points: ``M[:3, :3] @ p + M[:3, 3]`` per point (None: as they are).
    The translation is added last, so a large mine coordinate is rounded once."""
    if M is None:
        return np.asarray(points, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    xyz = p.reshape(*p.shape[:-1], -1, 3)
    return (xyz @ M[:3, :3].T + M[:3, 3]).reshape(p.shape)


def local_to_plan(found: Sequence[tuple[int, ET.Element]], source: str, tol: float = TMATRIX_TOL) -> np.ndarray | None:
    """The file's one local-to-plan matrix from its ``TMatrix`` elements (``(line, element)``, as the
    parser found them), checked; None when the file has none. Raises :class:`InputError` naming the
    line and the reason for a malformed or non-rigid matrix, or for two that differ."""
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise ConfigError(f"iredes.tmatrix_tol = {tol!r}: expected a small positive number (1e-6)")
    if not found:
        return None
    mats = [(line, _tmatrix(el, line, source, tol)) for line, el in found]
    line0, M = mats[0]
    differ = [line for line, other in mats[1:] if not np.array_equal(other, M)]
    if differ:
        raise InputError(f"{source}: {len(mats)} TMatrix elements (lines {[m[0] for m in mats]}), and the one at "
                         f"line(s) {differ} differs from the one at line {line0}: which frame places the holes is "
                         "unknown; a file has one")
    if len(mats) > 1:
        log.info("%s: %d equal TMatrix elements (lines %s); applied once", source, len(mats), [m[0] for m in mats])
    return M


def _number(text: str | None, where: str) -> float:
    s = (text or "").strip()
    try:
        value = float(s)
    except ValueError:
        raise InputError(f"{where} is {s!r}, not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{where} is {s!r}, not a finite number")
    return value


def _tmatrix(el: ET.Element, line: int, source: str, tol: float) -> np.ndarray:
    where = f"{source}: line {line}: TMatrix"
    cols = list(el)
    if not cols and not (el.text or "").strip():
        log.info("%s is empty: read as the identity (the file's points are taken as they are)", where)
        return np.eye(4)
    names = [_local(c.tag) for c in cols]
    if (el.text or "").strip() or names != ["Col"] * 4:
        raise InputError(f"{where}: expected four Col elements (the matrix's columns), found "
                         f"{names or 'text ' + repr((el.text or '').strip()[:40])}")
    M = np.empty((4, 4))
    for j, col in enumerate(cols):
        axes = [_local(c.tag) for c in col]
        if sorted(axes) != sorted(_COL_AXES) or (col.text or "").strip():
            raise InputError(f"{where}: Col {j + 1} holds {axes}; expected x, y, z, w once each")
        for c in col:
            M[_COL_AXES.index(_local(c.tag)), j] = _number(c.text, f"{where}: Col {j + 1} {_local(c.tag)}")
    last = M[3]
    if np.abs(last - [0.0, 0.0, 0.0, 1.0]).max() > tol:
        raise InputError(f"{where}: its last row (the w of each Col) is {last.tolist()}, expected [0, 0, 0, 1]: "
                         "a projective matrix, not a placement of the plan")
    R = M[:3, :3]
    off = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if off > tol or det <= 0:
        raise InputError(f"{where}: its 3x3 part is not a rotation (largest |R^T R - I| entry {off:.3g}, det "
                         f"{det:.9g}; tolerance {tol:g}, solve.iredes.tmatrix_tol): a scale or shear would change "
                         "the holes' lengths and angles, a reflection would mirror the plan")
    return M
