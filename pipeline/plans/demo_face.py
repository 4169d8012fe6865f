"""The demo face: a realistic, drillable round for the drift of the safety model (the reference horseshoe,
or any profile), designed on the safety model."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.tunnel import Horseshoe, Tunnel
from pipeline.plans.csv_plan import write_csv_plan
from pipeline.plans.iredes import write_iredes_plan
from pipeline.plans.model import COLLAR, COORDS, TOE, DrillPlan, plan_frame

DEMO_PLAN_DATE = "2026-01-01T00:00:00"  # fixed, so the same layout gives byte-identical files


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
        collar, direction = _outward_holes(x_face, points, normals, c, a)
        # a collar inset along one segment's normal can lie nearer the next segment of a profile: ask both
        inside = safety.tunnel.contains(collar[:, 1], collar[:, 2], inset - 1e-9)
        return (_worst(feed_clearance(safety, collar, direction)) >= margin) & inside

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


def _profile_perimeter(tunnel, z_from: float, spacing: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A profile's :func:`_perimeter`: evenly spaced points on its walls and roof (every segment but the
    floor's), from ``z_from`` up one side over the top to ``z_from`` up the other, and the outward normals."""
    _, rest = tunnel.paths()
    s0, s1 = rest.first_at_height(z_from), rest.length - rest.first_at_height(z_from, from_end=True)
    if not s1 > s0:
        raise ConfigError(f"demo face: contour_from = {z_from!r} m leaves no wall or roof of {tunnel.describe()} "
                          "for contour holes")
    return rest.at(torch.linspace(s0, s1, max(3, round((s1 - s0) / spacing) + 1), dtype=torch.float64))


def _profile_lifters(safety, x_face, depth, *, spacing, inset, lookout, max_angle, margin):
    """A profile's lifters: the middle of its floor gets the least inset and look-out (:func:`_look_out`), and
    lifters with those share the stretch of floor on either side where their feed beam stays clear, evenly
    spaced, each looking out along its own floor segment's normal (a sloped floor is followed)."""
    floor, _ = safety.tunnel.paths()
    mid = floor.at(torch.tensor([0.5 * floor.length], dtype=torch.float64))
    l_in, l_ang = _look_out(safety, x_face, depth, *mid, inset=inset, lookout=lookout, max_angle=max_angle,
                            margin=margin)

    def clear(s):
        pts, nrm = floor.at(s)
        return _worst(feed_clearance(safety, *_outward_holes(x_face, pts, nrm, l_in.expand_as(s),
                                                             l_ang.expand_as(s)))) >= margin

    half = torch.tensor([0.5 * floor.length], dtype=torch.float64)
    left = float(_bisect(clear, torch.zeros(1, dtype=torch.float64), half))
    right = floor.length - float(_bisect(lambda s: clear(floor.length - s), torch.zeros(1, dtype=torch.float64),
                                         half))
    n = max(2, round((right - left) / spacing) + 1)
    pts, nrm = floor.at(torch.linspace(left, right, n, dtype=torch.float64))
    return _outward_holes(x_face, pts, nrm, l_in.expand(n), l_ang.expand(n))


def _horseshoe_lifters(safety, x_face, depth, *, spacing, inset, lookout, max_angle, margin):
    """Lifters on the horseshoe's flat floor: the centre one's inset and angle, shared out to the widest y
    whose beam is clear, evenly spaced and looking down."""
    f64 = torch.float64
    mid = torch.tensor([[0.0, 0.0]], dtype=f64), torch.tensor([[0.0, -1.0]], dtype=f64)
    l_in, l_ang = _look_out(safety, x_face, depth, *mid, inset=inset, lookout=lookout, max_angle=max_angle,
                            margin=margin)

    def lifter_clear(y):
        pts = torch.stack([y, torch.zeros_like(y)], -1)
        c, a = l_in.expand_as(y), l_ang.expand_as(y)
        return _worst(feed_clearance(safety, *_outward_holes(x_face, pts, mid[1].expand_as(pts), c, a))) >= margin

    r = safety.tunnel.half_width
    y_max = float(-_bisect(lambda t: lifter_clear(-t), torch.tensor([-r], dtype=f64), torch.tensor([0.0], dtype=f64)))
    n_lift = max(2, round(2 * y_max / spacing) + 1)
    l_pts = torch.stack([torch.linspace(-y_max, y_max, n_lift, dtype=f64), torch.zeros(n_lift, dtype=f64)], -1)
    return _outward_holes(x_face, l_pts, mid[1].expand(n_lift, 2), l_in.expand(n_lift), l_ang.expand(n_lift))


def _grid(tunnel: Tunnel, spacing: float, burden: float, z_from: float) -> torch.Tensor:
    """Staggered rows (y, z), symmetric about the centre line, covering the profile."""
    r = max(-tunnel.y_range[0], tunnel.y_range[1])  # the horseshoe: its half width
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
    tunnel: Tunnel | None = None,
    *,
    safety: SafetyModel,
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
    """A realistic, drillable round for the reference horseshoe (5.0 x 5.7 m), deterministic, designed on
    ``safety`` (the composed boom, tunnel and safety distances: the caller builds it from its config).

    Hole types (ids): a parallel-hole cut near the centre-low part of the face, ``n_relief``
    large-diameter uncharged relief holes (R..) inside squares of loaded cut holes (C..);
    stoping holes (S..) on a staggered pattern ``stoping_spacing`` x ``burden``; lifters (L..)
    along the floor, looking down; contour holes (K..) along walls and arch, looking out. Cut
    and stoping holes are parallel to +x; all toes lie on the plane ``x_face + depth``.

    Drillability (docs/reference.md, sections 2 and 3): every collar lies inside the profile shrunk by ``inset``,
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
    tunnel = safety.tunnel if tunnel is None else tunnel
    if tunnel != safety.tunnel:
        raise ConfigError(f"demo face: tunnel {tunnel} differs from the safety model's {safety.tunnel}")
    if not (6.0 <= x_face <= 7.0):
        raise ConfigError(f"demo face: x_face = {x_face!r}: expected a face position in [6, 7] m "
                          "(docs/reference.md, section 3)")
    lengths = {"depth": depth, "stoping_spacing": stoping_spacing, "burden": burden, "min_gap": min_gap,
               "contour_spacing": contour_spacing, "lifter_spacing": lifter_spacing, "relief_gap": relief_gap}
    for key, v in lengths.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"demo face: {key} = {v!r}: expected a positive length (m)")
    wall_top = tunnel.wall_height if tunnel.kind == "horseshoe" else tunnel.z_range[1] - tunnel.z_range[0]
    if not 0 < contour_from < wall_top:
        raise ConfigError(f"demo face: contour_from = {contour_from!r}: expected a height in (0, {wall_top:g}) m "
                          f"({'wall height' if tunnel.kind == 'horseshoe' else 'the profile height'})")
    if not (0 < max_lookout_deg < 15 and inset >= 0 and lookout >= 0 and margin >= 0 and n_relief >= 1):
        raise ConfigError(
            f"demo face: max_lookout_deg = {max_lookout_deg!r} must be in (0, 15), inset = {inset!r}, "
            f"lookout = {lookout!r} and margin = {margin!r} >= 0, n_relief = {n_relief!r} >= 1"
        )
    f64 = torch.float64
    max_angle = math.radians(max_lookout_deg)

    # Perimeter: contour on walls and arch, lifters on the floor.
    horseshoe = tunnel.kind == "horseshoe"
    k_pts, k_nrm = (_perimeter if horseshoe else _profile_perimeter)(tunnel, contour_from, contour_spacing)
    k_in, k_ang = _look_out(safety, x_face, depth, k_pts, k_nrm, inset=inset, lookout=lookout,
                            max_angle=max_angle, margin=margin)
    contour = _outward_holes(x_face, k_pts, k_nrm, k_in, k_ang)
    if horseshoe:
        lifters = _horseshoe_lifters(safety, x_face, depth, spacing=lifter_spacing, inset=inset, lookout=lookout,
                                     max_angle=max_angle, margin=margin)
    else:
        lifters = _profile_lifters(safety, x_face, depth, spacing=lifter_spacing, inset=inset, lookout=lookout,
                                   max_angle=max_angle, margin=margin)

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
    name = f"demo face: {tunnel.describe()}, face at x = {x_face:g} m, depth {depth:g} m"
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


def write_demo_plan(safety: SafetyModel, folder: Path) -> list[Path]:
    """The demo face for this safety model, as CSV and as IREDES (the same holes)."""
    plan = demo_face(safety=safety)
    write_csv_plan(plan, folder / "demo_face.csv")
    write_iredes_plan(plan, folder / "demo_face.xml", created=DEMO_PLAN_DATE)
    return [folder / "demo_face.csv", folder / "demo_face.xml"]
