"""Drill plans: the holes of one round on a tunnel face, checked row by row, as 6-D hole poses.

A plan lists, per hole, its collar (start point on the face) and toe (end point), in metres
in the boom base frame (docs/reference.md, section 1: x toward the face, y on the tunnel centre line, z up
from the floor). The hole pose of paper 000 eq. 4 is ``[p, p + D * unit(toe - collar)]``: the
preview point lies D along the hole, whatever the hole's own length.

Readers never stop at a bad row: every row-level problem (a missing, non-numeric or
non-finite coordinate, an empty or duplicate id, a zero-length hole) is collected as a
:class:`RowProblem` naming the row and the hole id, and the good rows are still returned, so
a plan with one typo is still solved. Only file-level faults (no such file, an empty file, a
missing column, no good row at all) raise :class:`~pipeline.core.errors.InputError`.

The plan model and the row checks here; CSV in :mod:`pipeline.plans.csv_plan`, IREDES XML in
:mod:`pipeline.plans.iredes`; :func:`pipeline.plans.read.read_plan` picks by suffix.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.data.tables import COLLAR_COLUMNS, TOE_COLUMNS, collar_toe_poses

COLLAR = COLLAR_COLUMNS
TOE = TOE_COLUMNS
COORDS = COLLAR + TOE
REQUIRED = ["hole_id", *COORDS]
HOLE_TYPES = ("cut", "relief", "stoping", "lifter", "contour")
MIN_LENGTH = 1e-6  # m; a shorter hole has no usable direction (toe == collar)
# m from the rig (in the rig frame, after navigation): far beyond any boom's reach
MAX_COORD = 1e4
# m in the plan's own frame: mine grids reach 1e7 m (UTM northings); beyond this a value is a wrong unit,
# and it stays far below where squaring a coordinate overflows (1e154)
MAX_PLAN_COORD = 1e8
# Ids a spreadsheet would evaluate as a formula (OWASP "CSV injection"), unless a plain number, and
# control characters (they break CSV rows, logs and terminals): such a row is a row problem.
_FORMULA_START = ("=", "+", "-", "@")
_PLAIN_NUMBER = re.compile(r"[+-]?\d+(\.\d+)?")
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
SHOWN_PROBLEMS = 10  # problems quoted in a file-level error message
_NON_FINITE = r"[+-]?(nan|inf|infinity)"
_LEADING_ZERO = r"[+-]?0\d"  # "007": an id or name, not the number 7


@dataclass(frozen=True)
class RowProblem:
    """One bad row: ``row`` is its line in the file (CSV: the header is line 1; IREDES: the
    line of the ``<Hole>`` start tag), ``hole_id`` is "" when the id itself is missing."""

    row: int
    hole_id: str
    column: str
    message: str

    def describe(self, source: str | None = None) -> str:
        where = f"{source}: " if source else ""
        return f"{where}row {self.row}, hole {self.hole_id!r}, column '{self.column}': {self.message}"


@dataclass
class DrillPlan:
    """The good holes of a plan, the problems of its bad rows, and where it came from.

    ``holes``: ``hole_id`` (str), the six coordinate columns (float64, m, base frame),
    ``hole_type`` when known, and every other column of the source carried through.
    ``format``: ``"csv"``, ``"iredes"`` or ``"demo"``.
    """

    holes: pd.DataFrame
    problems: list[RowProblem] = field(default_factory=list)
    plan_id: str = ""
    name: str = ""
    source: str | None = None
    format: str = "csv"
    # each good hole's line in the file (None: 0, 1, ...), so the solution keeps the plan's order
    lines: np.ndarray | None = None
    # the bad rows: hole_id, line and their own carried columns (the problems say what is wrong)
    rejected: pd.DataFrame | None = None
    # IREDES ChkSum: verified / unverified / ignored; "not applicable" for formats without one
    checksum: str = "not applicable"
    checksum_detail: str = ""
    # when verified: the convention that matched ("documented": ChkSum 0, "empty-value": ChkSum empty)
    # and the line ends ("as written", or "converted (CRLF -> LF)" for a copy that changed only those)
    checksum_convention: str | None = None
    checksum_line_ends: str | None = None
    # IREDES TMatrix applied to the file's points (4x4, before the axis map); None when the file has none
    local_to_plan: np.ndarray | None = None
    # the rig's pose in the plan frame the holes were taken into the rig frame with
    # (pipeline.plans.navigation.RigPose); None: read as the file has them
    navigation: object | None = None

    def __len__(self) -> int:
        return len(self.holes)

    def poses(self, depth: float) -> torch.Tensor:
        return hole_poses(self, depth)

    def problems_frame(self) -> pd.DataFrame:
        """The problems as a table (row, hole_id, column, message), e.g. to log or write."""
        cols = ["row", "hole_id", "column", "message"]
        return pd.DataFrame([[p.row, p.hole_id, p.column, p.message] for p in self.problems], columns=cols)

    def report(self) -> list[str]:
        """One line per problem, naming the file, row, hole and column."""
        return [p.describe(self.source) for p in self.problems]

    def drop_rows(self, drop: np.ndarray, column: str, messages: list[str]) -> None:
        """Move the good holes where ``drop`` holds to the bad rows, each with its problem (``messages``, in
        the holes' order); raises :class:`InputError` when no good hole is left."""
        drop = np.asarray(drop, dtype=bool)
        if not drop.any():
            return
        lines = np.arange(len(self.holes)) if self.lines is None else np.asarray(self.lines)
        ids = self.holes["hole_id"].to_numpy()
        new = [RowProblem(int(lines[i]), str(ids[i]), column, m)
               for i, m in zip(np.flatnonzero(drop), messages, strict=True)]
        self.problems = sorted([*self.problems, *new], key=lambda p: p.row)
        if drop.all():
            shown = "; ".join(p.describe() for p in new[:SHOWN_PROBLEMS])
            raise InputError(f"{self.source}: no usable hole in {len(ids)} row(s): {shown}")
        gone = self.holes[drop].drop(columns=[c for c in COORDS if c in self.holes]).reset_index(drop=True)
        gone.insert(1, "line", lines[drop])
        self.rejected = gone if self.rejected is None else pd.concat([self.rejected, gone], ignore_index=True)
        self.holes = self.holes[~drop].reset_index(drop=True)
        self.lines = lines[~drop]

    def provenance(self) -> dict:
        """What the solution's JSON says about the file: the checksum state, its detail, the
        convention and line ends that matched (None unless verified), and the local-to-plan
        matrix applied (a 4x4 nested list of rows, None when none was)."""
        M = self.local_to_plan
        return {"checksum": self.checksum, "checksum_detail": self.checksum_detail,
                "checksum_convention": self.checksum_convention, "checksum_line_ends": self.checksum_line_ends,
                "local_to_plan": None if M is None else np.asarray(M, dtype=float).tolist()}


# ---------------------------------------------------------------------------------------------
# Checking rows (shared by the CSV and IREDES readers)


def _cell_kinds(text: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Values (NaN where not a finite number), stripped text, and a code per cell:
    0 ok, 1 missing, 2 non-numeric, 3 non-finite."""
    stripped = text.apply(lambda c: c.astype("string").fillna("").str.strip())
    values = stripped.apply(lambda c: pd.to_numeric(c, errors="coerce")).to_numpy(dtype=np.float64, na_value=np.nan)
    spelled = stripped.apply(lambda c: c.str.fullmatch(_NON_FINITE, case=False)).to_numpy(dtype=bool)
    empty = (stripped == "").to_numpy(dtype=bool)
    kind = np.zeros(values.shape, dtype=np.int8)
    kind[np.isinf(values) | spelled] = 3
    kind[np.isnan(values) & ~spelled] = 2
    kind[empty] = 1
    values[kind != 0] = np.nan
    return values, stripped.to_numpy(dtype=object), kind


_KIND_TEXT = {1: "missing value", 2: "non-numeric value {!r}", 3: "non-finite value {!r}"}


def infer_column_types(df: pd.DataFrame) -> pd.DataFrame:
    """Columns read as text become numbers where every non-empty value is one, as pandas types
    a CSV column (IREDES extras); the others stay text, and so does a column with a value such as
    ``007`` (a name or id: as a number it would lose its zeros and meet ``7``)."""
    out = df.copy()
    for col in out.columns:
        text = out[col].astype("string").fillna("").str.strip()
        nums = pd.to_numeric(text.replace("", None).astype(object), errors="coerce")
        numeric = (text.ne("").any() and nums.notna().eq(text.ne("")).all()
                   and not text.str.match(_LEADING_ZERO).any())
        out[col] = nums if numeric else text.astype(str)
    return out


def checked_plan(
    ids: Sequence[str],
    coord_text: pd.DataFrame,
    extras: pd.DataFrame,
    rows: np.ndarray,
    *,
    source: str,
    fmt: str,
    plan_id: str,
    name: str,
    labels: Sequence[str] = COORDS,
    to_base: Callable[[np.ndarray], np.ndarray] | None = None,
    id_label: str = "hole_id",
    length_label: str = "toe",
    min_length: float = MIN_LENGTH,
) -> DrillPlan:
    """Check every row and keep the good ones.

    ``coord_text``: six columns of text in the file's own order (collar then toe), named in
    messages by ``labels``; ``to_base`` maps the parsed ``(n, 6)`` numbers to base-frame
    metres (IREDES axes, units, origin). ``rows``: each row's line in the file.
    Raises :class:`InputError` when no row is good.
    """
    if not (isinstance(min_length, (int, float)) and min_length > 0):
        raise ConfigError(f"min_length = {min_length!r}: expected a positive length (m)")
    ids = np.asarray([str(i).strip() for i in ids], dtype=object)
    rows = np.asarray(rows, dtype=np.int64)
    values, text, kind = _cell_kinds(coord_text.reset_index(drop=True))
    bad = kind != 0
    problems: list[tuple[int, int, str, str]] = []  # (position, column order, column, message)
    for i, j in zip(*np.nonzero(bad), strict=True):
        problems.append((i, j + 1, labels[j], _KIND_TEXT[int(kind[i, j])].format(text[i, j])))
    empty_id = ids == ""
    for i in np.flatnonzero(empty_id):
        problems.append((i, 0, id_label, "empty hole id"))
    for i, hid in enumerate(ids):
        if _CONTROL.search(hid):
            problems.append((i, 0, id_label, f"hole id {hid!r} holds a control character; rename the hole"))
        elif hid.startswith(_FORMULA_START) and not _PLAIN_NUMBER.fullmatch(hid):
            problems.append((i, 0, id_label, f"hole id {hid!r} starts with {hid[0]!r}: a spreadsheet would run it "
                                              "as a formula; rename the hole"))
    series = pd.Series(ids)
    dup = series.duplicated(keep="first").to_numpy() & ~empty_id
    first = pd.Series(np.arange(len(ids))).groupby(ids).transform("min").to_numpy()
    for i in np.flatnonzero(dup):
        problems.append((i, 0, id_label, f"duplicate hole id {ids[i]!r} (first at row {rows[first[i]]})"))
    with np.errstate(over="ignore", invalid="ignore"):
        base = values if to_base is None else to_base(values)
        far = ~bad.any(axis=1, keepdims=True) & ~(np.abs(base) <= MAX_PLAN_COORD)  # a wrong unit, or overflowed
        for i, j in zip(*np.nonzero(far), strict=True):
            # an axis map mixes a point's columns: name the point (IREDES), or the column itself (CSV)
            label = labels[j] if to_base is None else labels[j].split("/")[0]
            problems.append((i, j + 1, label, f"coordinate {base[i, j]:.6g} m is beyond {MAX_PLAN_COORD:g} m, "
                                              "no coordinate of any mine: check the unit"))
        bad = bad | far
        length = np.linalg.norm(np.where(bad, 0.0, base)[:, 3:] - np.where(bad, 0.0, base)[:, :3], axis=1)
    short = ~bad.any(axis=1) & (length < min_length)
    for i in np.flatnonzero(short):
        problems.append((i, 7, length_label, f"zero-length hole: toe equals collar (length {length[i]:.3g} m)"))
    problems.sort(key=lambda p: (p[0], p[1]))
    found = [RowProblem(int(rows[i]), str(ids[i]), col, msg) for i, _, col, msg in problems]
    good = np.ones(len(ids), dtype=bool)
    good[[p[0] for p in problems]] = False
    if not good.any():
        shown = "; ".join(p.describe() for p in found[:SHOWN_PROBLEMS])
        more = f" (and {len(found) - SHOWN_PROBLEMS} more)" if len(found) > SHOWN_PROBLEMS else ""
        raise InputError(f"{source}: no usable hole in {len(ids)} row(s): {shown}{more}")
    holes = pd.DataFrame(base[good], columns=COORDS)
    holes.insert(0, "hole_id", pd.Series(ids[good], dtype=str))
    extras = extras.reset_index(drop=True)
    if "hole_type" in extras:
        extras["hole_type"] = extras["hole_type"].astype("string").fillna("").astype(str)
    holes = pd.concat([holes, extras.loc[good].reset_index(drop=True)], axis=1)
    rejected = pd.concat([pd.DataFrame({"hole_id": pd.Series(ids[~good], dtype=str), "line": rows[~good]}),
                          extras.loc[~good].reset_index(drop=True)], axis=1)
    return DrillPlan(holes, found, plan_id=plan_id, name=name, source=source, format=fmt, lines=rows[good],
                     rejected=rejected)


def plan_frame(plan: DrillPlan | pd.DataFrame) -> pd.DataFrame:
    """The holes table in file order: id, type, coordinates, then the carried columns."""
    holes = plan.holes if isinstance(plan, DrillPlan) else plan
    missing = [c for c in REQUIRED if c not in holes.columns]
    if missing:
        raise InputError(f"drill plan table: missing column(s) {missing}; found {list(holes.columns)}")
    first = ["hole_id", *(["hole_type"] if "hole_type" in holes else []), *COORDS]
    return holes[first + [c for c in holes.columns if c not in first]]


# ---------------------------------------------------------------------------------------------
# Poses


def hole_poses(plan: DrillPlan | pd.DataFrame, depth: float) -> torch.Tensor:
    """``(n, 6)`` float64 hole poses ``[p, p + depth * unit(toe - collar)]`` (paper 000 eq. 4)."""
    if isinstance(depth, bool) or not isinstance(depth, (int, float)) or not math.isfinite(depth) or depth <= 0:
        raise ConfigError(f"preview depth = {depth!r}: expected a positive number (m)")
    holes = plan_frame(plan)
    collar, toe = holes[COLLAR].to_numpy(dtype=np.float64), holes[TOE].to_numpy(dtype=np.float64)
    length = np.linalg.norm(toe - collar, axis=1)
    if not np.all(length >= MIN_LENGTH):
        i = int(np.argmin(length))
        raise InputError(f"hole {holes['hole_id'].iloc[i]!r}: zero-length hole (length {float(length[i]):.3g} m)")
    return collar_toe_poses(collar, toe, depth)
