"""Drill plans: the holes of one round on a tunnel face, checked row by row, as 6-D hole poses.

A plan lists, per hole, its collar (start point on the face) and toe (end point), in metres
in the boom base frame (spec sect. 1: x toward the face, y on the tunnel centre line, z up
from the floor). The hole pose of paper 000 eq. 4 is ``[p, p + D * unit(toe - collar)]``: the
preview point lies D along the hole, whatever the hole's own length.

Readers never stop at a bad row: every row-level problem (a missing, non-numeric or
non-finite coordinate, an empty or duplicate id, a zero-length hole) is collected as a
:class:`RowProblem` naming the row and the hole id, and the good rows are still returned, so
a plan with one typo is still solved. Only file-level faults (no such file, an empty file, a
missing column, no good row at all) raise :class:`~pipeline.core.errors.InputError`.

CSV here; IREDES XML in :mod:`pipeline.data.iredes`; :func:`read_plan` picks by suffix.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.io import write_csv
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.tunnel import Horseshoe

COLLAR = ["collar_x", "collar_y", "collar_z"]
TOE = ["toe_x", "toe_y", "toe_z"]
COORDS = COLLAR + TOE
REQUIRED = ["hole_id", *COORDS]
HOLE_TYPES = ("cut", "relief", "stoping", "lifter", "contour")
MIN_LENGTH = 1e-6  # m; a shorter hole has no usable direction (toe == collar)
SHOWN_PROBLEMS = 10  # problems quoted in a file-level error message
_NON_FINITE = r"[+-]?(nan|inf|infinity)"


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
    a CSV column (IREDES extras); the others stay text."""
    out = df.copy()
    for col in out.columns:
        text = out[col].astype("string").fillna("").str.strip()
        nums = pd.to_numeric(text.replace("", None).astype(object), errors="coerce")
        numeric = text.ne("").any() and nums.notna().eq(text.ne("")).all()
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
    series = pd.Series(ids)
    dup = series.duplicated(keep="first").to_numpy() & ~empty_id
    first = pd.Series(np.arange(len(ids))).groupby(ids).transform("min").to_numpy()
    for i in np.flatnonzero(dup):
        problems.append((i, 0, id_label, f"duplicate hole id {ids[i]!r} (first at row {rows[first[i]]})"))
    base = values if to_base is None else to_base(values)
    length = np.linalg.norm(base[:, 3:] - base[:, :3], axis=1)
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
    extras = extras.reset_index(drop=True).loc[good].reset_index(drop=True)
    if "hole_type" in extras:
        extras["hole_type"] = extras["hole_type"].astype("string").fillna("").astype(str)
    holes = pd.concat([holes, extras], axis=1)
    return DrillPlan(holes, found, plan_id=plan_id, name=name, source=source, format=fmt)


# ---------------------------------------------------------------------------------------------
# CSV


def _read_csv_text(path: Path, **kw) -> pd.DataFrame:
    try:
        # Blank lines are kept (and dropped below) so that row i is line i + 2 of the file.
        df = pd.read_csv(path, skip_blank_lines=False, **kw)
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: empty file; expected a header with columns {REQUIRED}") from None
    except (pd.errors.ParserError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a readable CSV file: {e}") from None
    df.columns = [str(c).strip() for c in df.columns]
    return df


def read_csv_plan(path: str | Path, *, min_length: float = MIN_LENGTH) -> DrillPlan:
    """Read a CSV drill plan (columns :data:`REQUIRED`, metres, base frame; others carried).

    Row numbers in problems are file lines (header = line 1). Raises :class:`InputError` for a
    missing file, an empty file, a missing column (naming the missing and the found ones) or a
    file without a single good row.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such drill plan")
    # Text for the checked columns (ids keep leading zeros, bad numbers keep their spelling);
    # pandas' own typing for the carried columns.
    text = _read_csv_text(path, dtype=str, keep_default_na=False)
    missing = [c for c in REQUIRED if c not in text.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {missing}; found {list(text.columns)}")
    blank = text.apply(lambda c: c.astype("string").fillna("").str.strip().eq("")).all(axis=1).to_numpy()
    if blank.all():
        raise InputError(f"{path}: no holes (only a header)")
    typed = _read_csv_text(path)
    keep = np.flatnonzero(~blank)
    extras = typed.loc[keep, [c for c in typed.columns if c not in REQUIRED]]
    return checked_plan(
        text.loc[keep, "hole_id"].tolist(),
        text.loc[keep, COORDS],
        extras,
        keep + 2,
        source=str(path),
        fmt="csv",
        plan_id=path.stem,
        name=path.stem,
        min_length=min_length,
    )


def plan_frame(plan: DrillPlan | pd.DataFrame) -> pd.DataFrame:
    """The holes table in file order: id, type, coordinates, then the carried columns."""
    holes = plan.holes if isinstance(plan, DrillPlan) else plan
    missing = [c for c in REQUIRED if c not in holes.columns]
    if missing:
        raise InputError(f"drill plan table: missing column(s) {missing}; found {list(holes.columns)}")
    first = ["hole_id", *(["hole_type"] if "hole_type" in holes else []), *COORDS]
    return holes[first + [c for c in holes.columns if c not in first]]


def write_csv_plan(plan: DrillPlan | pd.DataFrame, path: str | Path) -> None:
    """Write a plan as CSV, atomically (floats at full precision: a re-read gives the same holes)."""
    write_csv(plan_frame(plan), path)


def read_plan(path: str | Path, **kw) -> DrillPlan:
    """A CSV (``.csv``) or IREDES (``.xml``) plan; ``kw`` goes to the reader."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return read_csv_plan(path, **kw)
    if suffix == ".xml":
        from pipeline.data.iredes import read_iredes_plan

        return read_iredes_plan(path, **kw)
    raise InputError(f"{path}: unknown drill plan format '{suffix}'; expected .csv or .xml (IREDES)")


# ---------------------------------------------------------------------------------------------
# Poses


def hole_poses(plan: DrillPlan | pd.DataFrame, depth: float) -> torch.Tensor:
    """``(n, 6)`` float64 hole poses ``[p, p + depth * unit(toe - collar)]`` (paper 000 eq. 4)."""
    if isinstance(depth, bool) or not isinstance(depth, (int, float)) or not math.isfinite(depth) or depth <= 0:
        raise ConfigError(f"preview depth = {depth!r}: expected a positive number (m)")
    holes = plan_frame(plan)
    collar = holes[COLLAR].to_numpy(dtype=np.float64)
    axis = holes[TOE].to_numpy(dtype=np.float64) - collar
    length = np.linalg.norm(axis, axis=1, keepdims=True)
    if not np.all(length >= MIN_LENGTH):
        i = int(np.argmin(length))
        raise InputError(f"hole {holes['hole_id'].iloc[i]!r}: zero-length hole (length {float(length[i, 0]):.3g} m)")
    return torch.from_numpy(np.concatenate([collar, collar + depth * axis / length], axis=1))


# ---------------------------------------------------------------------------------------------
# Demo face


def reference_safety(tunnel: Horseshoe | None = None) -> SafetyModel:
    """The reference boom ``jumbo8`` with the paper's safety distances in ``tunnel``."""
    from pipeline.core.build import build_safety, load_boom
    from pipeline.core.config import load_group_file

    tunnel_cfg = load_group_file("tunnel", "horseshoe")
    if tunnel is not None:
        tunnel_cfg = {"width": tunnel.width, "wall_height": tunnel.wall_height}
    return build_safety(load_boom("jumbo8"), tunnel_cfg, load_group_file("safety", "paper"))


def feed_clearance(safety: SafetyModel, collar: torch.Tensor, direction: torch.Tensor) -> dict[str, torch.Tensor]:
    """Wall, ground and arch clearance (m) of the feed beam at these holes, whatever the joints."""
    return safety.tool_body_clearances(collar, direction)


def _worst(clear: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.minimum(torch.minimum(clear["wall"], clear["ground"]), clear["arch"])


def _bisect(pred: Callable[[torch.Tensor], torch.Tensor], lo: torch.Tensor, hi: torch.Tensor, iters: int = 40):
    """Per element, the smallest t in [lo, hi] where a false-then-true ``pred`` holds (the
    feasible end of the final bracket, so ``pred`` holds there whenever it holds at ``hi``)."""
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        ok = pred(mid)
        lo, hi = torch.where(ok, lo, mid), torch.where(ok, mid, hi)
    return hi


def _perimeter(tunnel: Horseshoe, z_from: float, spacing: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Evenly spaced points (y, z) on walls and arch, from one wall at ``z_from`` over the crown
    to the other, and the outward unit normals there."""
    r, h = tunnel.half_width, tunnel.wall_height
    wall, arc = h - z_from, math.pi * r
    total = 2 * wall + arc
    s = torch.linspace(0.0, total, max(3, round(total / spacing) + 1), dtype=torch.float64)
    phi = (math.pi - (s - wall) / r).clamp(0.0, math.pi)
    on_left, on_right = s < wall, s > wall + arc
    y = torch.where(on_left, -r, torch.where(on_right, r, r * torch.cos(phi)))
    z = torch.where(on_left, z_from + s, torch.where(on_right, h - (s - wall - arc), h + r * torch.sin(phi)))
    ny = torch.where(on_left, -1.0, torch.where(on_right, 1.0, torch.cos(phi)))
    nz = torch.where(on_left | on_right, 0.0, torch.sin(phi))
    return torch.stack([y, z], -1), torch.stack([ny, nz], -1)


def _outward_holes(x_face, points, normals, inset, angle):
    """Collars ``inset`` inside the profile points, directions tilted ``angle`` outward."""
    n = points.shape[0]
    collar = torch.cat([torch.full((n, 1), x_face, dtype=torch.float64), points - inset[:, None] * normals], -1)
    direction = torch.cat([torch.cos(angle)[:, None], torch.sin(angle)[:, None] * normals], -1)
    return collar, direction


def _look_out(safety, x_face, depth, points, normals, *, inset, lookout, max_angle, margin, max_inset=1.5):
    """Per perimeter hole, the collar inset and look-out angle (rad).

    The inset is the least (>= ``inset``) that keeps every feed-beam clearance >= ``margin``;
    the angle the least (<= ``max_angle``) that puts the toe, on the plane ``depth`` ahead of
    the face, ``lookout`` beyond the profile. More look-out needs less inset (the beam behind
    the collar tilts inward), so both are found by nested bisection, vectorised over holes.
    """
    n = points.shape[0]

    def clear_at(c, a):
        return _worst(feed_clearance(safety, *_outward_holes(x_face, points, normals, c, a))) >= margin

    def inset_for(a):
        lo, hi = torch.full((n,), float(inset), dtype=torch.float64), torch.full((n,), max_inset, dtype=torch.float64)
        if not bool(clear_at(hi, a).all()):
            i = int(torch.nonzero(~clear_at(hi, a))[0])
            y, z = points[i].tolist()
            raise ConfigError(
                f"demo face: no collar within {max_inset} m of the profile at (y={y:.2f}, z={z:.2f}) keeps the "
                f"feed beam clear; lower the safety distances or raise the contour start"
            )
        return torch.where(clear_at(lo, a), lo, _bisect(lambda c: clear_at(c, a), lo, hi, iters=32))

    def reaches(a):
        return depth * torch.tan(a) - inset_for(a) >= lookout

    zero, top = torch.zeros(n, dtype=torch.float64), torch.full((n,), max_angle, dtype=torch.float64)
    angle = torch.where(reaches(top), _bisect(reaches, zero, top, iters=24), top)
    return inset_for(angle), angle


def _grid(tunnel: Horseshoe, spacing: float, burden: float, z_from: float) -> torch.Tensor:
    """Staggered rows (y, z), symmetric about the centre line, covering the profile."""
    r = tunnel.half_width
    rows = torch.arange(z_from, tunnel.crown, burden, dtype=torch.float64)
    cols = torch.arange(-math.floor(r / spacing) - 1, math.floor(r / spacing) + 2, dtype=torch.float64) * spacing
    shift = (torch.arange(len(rows)) % 2).to(torch.float64)[:, None] * (0.5 * spacing)
    y = cols[None, :] + shift
    z = rows[:, None].expand_as(y)
    return torch.stack([y.reshape(-1), z.reshape(-1)], -1)


def _cut(centre: tuple[float, float], radii: Sequence[float], n_relief: int, relief_gap: float):
    """Relief holes on a short horizontal line at the centre, and squares of loaded cut holes
    around them, each square turned 45 degrees from the one inside it."""
    yc, zc = centre
    offsets = (torch.arange(n_relief, dtype=torch.float64) - 0.5 * (n_relief - 1)) * relief_gap
    relief = torch.stack([yc + offsets, torch.full_like(offsets, zc)], -1)
    squares = []
    for k, a in enumerate(radii):
        ang = torch.arange(4, dtype=torch.float64) * (math.pi / 2) + (math.pi / 4) * (k % 2)
        squares.append(torch.stack([yc + a * torch.cos(ang), zc + a * torch.sin(ang)], -1))
    return relief, torch.cat(squares)


def _min_distance(points: torch.Tensor, others: torch.Tensor) -> torch.Tensor:
    return torch.cdist(points, others).amin(dim=1)


def _frame(kind, prefix, collar, direction, length, diameter_mm):
    n = collar.shape[0]
    toe = collar + length[:, None] * direction
    # Nanometre coordinates: a readable file (0.25, not 0.24999999999999997), and within the
    # 1e-9 m tolerance of the drillability check.
    df = pd.DataFrame(np.round(torch.cat([collar, toe], -1).numpy(), 9) + 0.0, columns=COORDS)
    df.insert(0, "hole_type", kind)
    df.insert(0, "hole_id", [f"{prefix}{k + 1:02d}" for k in range(n)])
    df["diameter_mm"] = diameter_mm
    return df


def demo_face(
    tunnel: Horseshoe | None = None,
    *,
    safety: SafetyModel | None = None,
    x_face: float = 6.5,
    depth: float = 3.5,
    cut_centre: tuple[float, float] = (0.0, 1.6),
    cut_radii: Sequence[float] = (0.25, 0.5, 0.95),
    n_relief: int = 2,
    relief_gap: float = 0.2,
    stoping_spacing: float = 0.75,
    burden: float = 0.7,
    min_gap: float = 0.5,
    contour_spacing: float = 0.55,
    contour_from: float = 0.7,
    lifter_spacing: float = 0.75,
    lookout: float = 0.1,
    max_lookout_deg: float = 11.0,
    inset: float = 0.2,
    margin: float = 0.02,
    diameter_mm: int = 48,
    relief_diameter_mm: int = 102,
) -> DrillPlan:
    """A realistic, drillable round for the reference horseshoe (5.0 x 5.7 m), deterministic.

    Hole types (ids): a parallel-hole cut near the centre-low part of the face, ``n_relief``
    large-diameter uncharged relief holes (R..) inside squares of loaded cut holes (C..);
    stoping holes (S..) on a staggered pattern ``stoping_spacing`` x ``burden``; lifters (L..)
    along the floor, looking down; contour holes (K..) along walls and arch, looking out. Cut
    and stoping holes are parallel to +x; all toes lie on the plane ``x_face + depth``.

    Drillability (spec sect. 2-3): every collar lies inside the profile shrunk by ``inset``,
    every direction within ``max_lookout_deg`` of +x, and the feed beam at every hole (collar
    minus 4.5 m along the hole, its front metre excepted, radius 0.15 m) keeps the wall
    (0.5 m), ground and arch (0.1 m) safety distances with ``margin`` to spare, checked with
    :meth:`SafetyModel.tool_body_clearances`. So a parallel hole's collar must stay 0.67 m
    from the walls and 0.27 m from floor and arch, far more than the 0.2 m inset.

    Why the look-out is not simply "a few degrees, shrunk until it holds": here the look-out
    *helps* the beam. The beam lies behind the collar, so tilting the hole outward by ``a``
    moves the first checked beam point (1 m behind the collar) ``sin a`` metres inward. What
    must shrink is therefore the collar's distance to the profile, not the angle: each
    perimeter hole gets the least inset that keeps the beam clear (found by bisection on the
    safety model itself) and the least look-out that puts its toe ``lookout`` beyond the
    profile, so the next round keeps its section, capped at ``max_lookout_deg``. With the
    defaults, arch holes and lifters keep the 0.2 m inset and look out about 5 degrees; wall
    holes, bound by the 0.5 m wall distance, sit about 0.5 m in and look out about 10 degrees.
    Stoping holes are the grid points whose (parallel) beam is clear, at least ``min_gap``
    from every other hole. Any remaining violation raises :class:`ConfigError`.
    """
    safety = safety if safety is not None else reference_safety(tunnel)
    tunnel = safety.tunnel if tunnel is None else tunnel
    if tunnel != safety.tunnel:
        raise ConfigError(f"demo face: tunnel {tunnel} differs from the safety model's {safety.tunnel}")
    if not (6.0 <= x_face <= 7.0):
        raise ConfigError(f"demo face: x_face = {x_face!r}: expected a face position in [6, 7] m (spec sect. 3)")
    lengths = {"depth": depth, "stoping_spacing": stoping_spacing, "burden": burden, "min_gap": min_gap,
               "contour_spacing": contour_spacing, "lifter_spacing": lifter_spacing, "relief_gap": relief_gap}
    for key, v in lengths.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"demo face: {key} = {v!r}: expected a positive length (m)")
    if not 0 < contour_from < tunnel.wall_height:
        raise ConfigError(f"demo face: contour_from = {contour_from!r}: expected a height in (0, wall height) m")
    if not (0 < max_lookout_deg < 15 and inset >= 0 and lookout >= 0 and margin >= 0 and n_relief >= 1):
        raise ConfigError(
            f"demo face: max_lookout_deg = {max_lookout_deg!r} must be in (0, 15), inset = {inset!r}, "
            f"lookout = {lookout!r} and margin = {margin!r} >= 0, n_relief = {n_relief!r} >= 1"
        )
    f64 = torch.float64
    max_angle = math.radians(max_lookout_deg)

    # Perimeter: contour on walls and arch, lifters on the floor.
    k_pts, k_nrm = _perimeter(tunnel, contour_from, contour_spacing)
    k_in, k_ang = _look_out(safety, x_face, depth, k_pts, k_nrm, inset=inset, lookout=lookout,
                            max_angle=max_angle, margin=margin)
    mid = torch.tensor([[0.0, 0.0]], dtype=f64), torch.tensor([[0.0, -1.0]], dtype=f64)
    l_in, l_ang = _look_out(safety, x_face, depth, *mid, inset=inset, lookout=lookout, max_angle=max_angle,
                            margin=margin)
    # Lifters share the centre one's inset and angle, out to the widest y whose beam is clear.
    def lifter_clear(y):
        pts = torch.stack([y, torch.zeros_like(y)], -1)
        c, a = l_in.expand_as(y), l_ang.expand_as(y)
        return _worst(feed_clearance(safety, *_outward_holes(x_face, pts, mid[1].expand_as(pts), c, a))) >= margin

    r = tunnel.half_width
    y_max = float(-_bisect(lambda t: lifter_clear(-t), torch.tensor([-r], dtype=f64), torch.tensor([0.0], dtype=f64)))
    n_lift = max(2, round(2 * y_max / lifter_spacing) + 1)
    l_pts = torch.stack([torch.linspace(-y_max, y_max, n_lift, dtype=f64), torch.zeros(n_lift, dtype=f64)], -1)
    l_nrm = mid[1].expand(n_lift, 2)
    contour = _outward_holes(x_face, k_pts, k_nrm, k_in, k_ang)
    lifters = _outward_holes(x_face, l_pts, l_nrm, l_in.expand(n_lift), l_ang.expand(n_lift))

    # Cut and stoping: parallel holes.
    relief, cut = _cut(cut_centre, cut_radii, n_relief, relief_gap)
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=f64)

    def parallel(yz):
        collar = torch.cat([torch.full((yz.shape[0], 1), x_face, dtype=f64), yz], -1)
        return collar, ex.expand(yz.shape[0], 3)

    placed = torch.cat([relief, cut, contour[0][:, 1:], lifters[0][:, 1:]])
    grid = _grid(tunnel, stoping_spacing, burden, float(lifters[0][0, 2]) + burden)
    ok = (_worst(feed_clearance(safety, *parallel(grid))) >= margin) & (_min_distance(grid, placed) >= min_gap)
    stoping = grid[ok]

    groups = [
        ("cut", "C", parallel(cut), diameter_mm),
        ("relief", "R", parallel(relief), relief_diameter_mm),
        ("stoping", "S", parallel(stoping), diameter_mm),
        ("lifter", "L", lifters, diameter_mm),
        ("contour", "K", contour, diameter_mm),
    ]
    frames = [_frame(kind, prefix, c, d, depth / d[:, 0], dia) for kind, prefix, (c, d), dia in groups]
    holes = pd.concat(frames, ignore_index=True)
    _check_drillable(safety, holes, inset, max_lookout_deg)
    name = f"demo face: horseshoe {tunnel.width:g} x {tunnel.crown:g} m, face at x = {x_face:g} m, depth {depth:g} m"
    return DrillPlan(holes, [], plan_id="demo_face", name=name, source=None, format="demo")


def plan_clearances(safety: SafetyModel, plan: DrillPlan | pd.DataFrame) -> dict[str, torch.Tensor]:
    """Feed-beam clearance to wall, ground and arch (m) of every hole of a plan."""
    holes = plan_frame(plan)
    collar = torch.tensor(holes[COLLAR].to_numpy(dtype=np.float64))
    axis = torch.tensor(holes[TOE].to_numpy(dtype=np.float64)) - collar
    return feed_clearance(safety, collar, axis / axis.norm(dim=-1, keepdim=True))


def _check_drillable(safety: SafetyModel, holes: pd.DataFrame, inset: float, max_deg: float) -> None:
    worst = _worst(plan_clearances(safety, holes))
    collar = torch.tensor(holes[COLLAR].to_numpy(dtype=np.float64))
    axis = torch.tensor(holes[TOE].to_numpy(dtype=np.float64)) - collar
    angle = torch.rad2deg(torch.acos((axis[:, 0] / axis.norm(dim=-1)).clamp(-1, 1)))
    inside = safety.tunnel.contains(collar[:, 1], collar[:, 2], inset - 1e-9)
    bad = (worst < 0) | ~inside | (angle > max_deg + 1e-9)
    if bool(bad.any()):
        i = int(torch.nonzero(bad)[0])
        raise ConfigError(
            f"demo face: hole {holes['hole_id'].iloc[i]} is not drillable (feed clearance {float(worst[i]):.3f} m, "
            f"inside profile less {inset} m: {bool(inside[i])}, angle {float(angle[i]):.1f} deg); adjust the layout"
        )
