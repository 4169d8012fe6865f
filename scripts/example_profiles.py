"""Writes the example tunnel profiles of conf/tunnel/profiles/ (docs/plans_to_rig.md, "Tunnel profiles").

    python scripts/example_profiles.py        # rewrites the CSVs, byte for byte the same

Each is a closed polyline (y, z, surface) in the rig frame, counter-clockwise from the right floor corner;
the segment from a vertex to the next has the kind of its first vertex. Arcs are inscribed polylines: a
chord error (sagitta) of r (1 - cos(step / 2)), under 3 mm for every arc here.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

OUT = Path(__file__).resolve().parents[1] / "conf" / "tunnel" / "profiles"


def arc(cy, cz, r, a0, a1, n):
    """n + 1 points on the circle (cy, cz, r) from angle a0 to a1 (degrees, counter-clockwise)."""
    return [(cy + r * math.cos(math.radians(a0 + (a1 - a0) * k / n)),
             cz + r * math.sin(math.radians(a0 + (a1 - a0) * k / n))) for k in range(n + 1)]


def outline(parts):
    """Vertices and kinds from (kind, points) parts in order; a part's last point starts the next part."""
    rows = []
    for kind, pts in parts:
        for y, z in pts[:-1]:
            rows.append((round(y, 6) + 0.0, round(z, 6) + 0.0, kind))
    return pd.DataFrame(rows, columns=["y", "z", "surface"])


def horseshoe(width=5.0, wall_height=3.2, n_arc=64):
    """The reference horseshoe (floor, vertical walls, semicircular arch) as a polyline."""
    r = width / 2
    return outline([("ground", [(r, 0.0), (-r, 0.0)]), ("wall", [(-r, 0.0), (-r, wall_height)]),
                    ("arch", arc(0.0, wall_height, r, 180.0, 0.0, n_arc)), ("wall", [(r, wall_height), (r, 0.0)])])


def d_shape(width=5.0, wall_height=3.6, crown=5.0, n_arc=32):
    """A D-shaped drift: flat floor, vertical walls, a segmental (flatter than semicircular) roof."""
    half, rise = width / 2, crown - wall_height
    r = (half * half + rise * rise) / (2 * rise)
    cz = crown - r
    a = math.degrees(math.atan2(wall_height - cz, half))
    return outline([("ground", [(half, 0.0), (-half, 0.0)]), ("wall", [(-half, 0.0), (-half, wall_height)]),
                    ("arch", arc(0.0, cz, r, 180.0 - a, a, n_arc)), ("wall", [(half, wall_height), (half, 0.0)])])


def flat_roof(width=5.5, roof=4.5, corner=0.6, fall=0.02, n_corner=8):
    """A box drift: floor falling ``fall`` (2 %) toward the right-hand drain, vertical walls up to the
    roof's rounded corners, a flat roof (kind arch: the roof is what the arch safety distance keeps)."""
    half, top = width / 2, roof - corner  # walls end where the corners start
    right, left = -fall * half, fall * half  # floor z at y = +half and -half; the centre line stays at z = 0
    roof_pts = [*arc(-half + corner, top, corner, 180.0, 90.0, n_corner), *arc(half - corner, top, corner, 90.0, 0.0,
                                                                               n_corner)]
    return outline([("ground", [(half, right), (0.0, 0.0), (-half, left)]), ("wall", [(-half, left), (-half, top)]),
                    ("arch", roof_pts), ("wall", [(half, top), (half, right)])])


def three_centred(width=6.0, wall_height=3.2, crown=5.5, side_r=1.5, n=24):
    """A road-tunnel style roof of three circular arcs: two of radius ``side_r`` at the shoulders
    tangent to the walls, one large crown arc tangent to both."""
    half = width / 2
    # shoulder centres (+-(half - side_r), wall_height); crown centre (0, cz) with radius R, tangent to both:
    # R - side_r = distance between centres; R = crown - cz.
    sy = half - side_r
    # (crown - cz - side_r)^2 = sy^2 + (wall_height - cz)^2  ->  solve for cz
    k = crown - side_r
    cz = (k * k - sy * sy - wall_height * wall_height) / (2 * (k - wall_height))
    R = crown - cz
    phi = math.degrees(math.atan2(wall_height - cz, sy))  # the tangent direction from the crown centre
    shoulder_l = arc(-sy, wall_height, side_r, 180.0, 180.0 - phi, n // 3)
    top = arc(0.0, cz, R, 180.0 - phi, phi, n)
    shoulder_r = arc(sy, wall_height, side_r, phi, 0.0, n // 3)
    return outline([("ground", [(half, 0.0), (-half, 0.0)]), ("wall", [(-half, 0.0), (-half, wall_height)]),
                    ("arch", shoulder_l + top[1:] + shoulder_r[1:]), ("wall", [(half, wall_height), (half, 0.0)])])


PROFILES = {
    "horseshoe_5x5.7.csv": horseshoe,
    "d_5x5.csv": d_shape,
    "box_5.5x4.5.csv": flat_roof,
    "three_centred_6x5.5.csv": three_centred,
}

if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    for name, make in PROFILES.items():
        table = make()
        step = (table[["y", "z"]].to_numpy() - table[["y", "z"]].shift(-1, fill_value=0).to_numpy())[:-1]
        assert (abs(step).sum(axis=1) > 1e-6).all(), f"{name}: a repeated vertex"
        table.to_csv(OUT / name, index=False, lineterminator="\n")
        print(OUT / name)
