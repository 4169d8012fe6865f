"""A boom from its YAML (``conf/boom/<name>.yaml``): modified D-H forward kinematics in numpy, the
collision bodies (capsules) and a lever-arm bound of how far a body point moves per unit of each joint;
optionally a calibrated model on it (a ``boom-ik/error-model/1`` file, docs/calibration.md).

Modified (Craig) D-H, docs/reference.md section 1: ``T(i-1, i) = RotX(alpha_{i-1}) TransX(a_{i-1}) RotZ(theta_i)
TransZ(d_i)``; YAML row i holds alpha_{i-1}, a_{i-1} and the offsets of theta_i and d_i.

A calibrated row is ``E_i T(i-1, i)``: the error twist ``xi_i = (rx, ry, rz, tx, ty, tz)`` is written in
the row's axis frame ``P_i = RotX(alpha_{i-1}) TransX(a_{i-1})``, so ``E_i = P_i exp(hat(xi_i)) P_i^-1``.
The exponential here is the 4 x 4 matrix series with scaling and squaring, not the closed form the
planner uses (its adjoint, then Rodrigues), so the two are independent ways to the same transform.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError

_ANGLE = {"deg": math.pi / 180.0, "rad": 1.0}
_LENGTH = {"m": 1.0, "mm": 1e-3}


@dataclass(frozen=True)
class Body:
    """A capsule between two points, each ``frame`` (an index, or ``n`` for the tool) plus ``offset``
    (in that frame); ``skip_end`` metres at its end are not checked against the tunnel."""

    name: str
    frames: tuple[int, int]
    offsets: np.ndarray  # (2, 3) in each point's frame
    radius: float
    skip_end: float


class BoomModel:
    """One boom type: joints (names, kinds, ranges in rad / m) and its bodies."""

    def __init__(self, node: dict, where: str):
        self.where = where
        try:
            self._parse(node)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: not a boom description this checker reads ({type(e).__name__}: {e})") from None

    def _parse(self, node: dict) -> None:
        if node.get("convention", "modified") != "modified":
            raise InputError(f"{self.where}: convention {node['convention']!r}: the checker reads modified D-H only")
        ang = _ANGLE[node.get("angle_unit", "deg")]
        lng = _LENGTH[node.get("length_unit", "m")]
        self.name = str(node["name"])
        rows = node["dh"]
        self.alpha = np.array([float(r["alpha"]) * ang for r in rows])
        self.a = np.array([float(r["a"]) * lng for r in rows])
        self.theta0 = np.array([float(r["theta"]) * ang for r in rows])
        self.d0 = np.array([float(r["d"]) * lng for r in rows])
        n = len(rows)
        self.joint_names = [str(j["name"]) for j in node["joints"]]
        self.joint_row = np.array([int(j["row"]) - 1 for j in node["joints"]])  # 0-based D-H row
        self.revolute = np.array([j["param"] == "theta" for j in node["joints"]])
        rows_ok = ((0 <= self.joint_row) & (self.joint_row < n)).all()
        if not set(p["param"] for p in node["joints"]) <= {"theta", "d"} or not rows_ok:
            raise InputError(f"{self.where}: a joint's param must be theta or d, its row within the {n} D-H rows")
        unit = np.where(self.revolute, ang, lng)
        self.lo = np.array([float(j["range"][0]) for j in node["joints"]]) * unit
        self.hi = np.array([float(j["range"][1]) for j in node["joints"]]) * unit
        # A joint whose range spans a full turn has no stop: it is judged modulo a turn (spec: +-180 deg).
        self.full_turn = self.revolute & (self.hi - self.lo >= 2 * math.pi - 1e-9)
        self.n_rows = n
        self.tool = np.array([float(v) * lng for v in node.get("tool", [0, 0, 0])])
        self.preview_depth = float(node.get("preview_depth", 0.0)) * lng
        self.bodies = [self._body(k, v, lng) for k, v in node["bodies"].items()]
        names = [b.name for b in self.bodies]
        self.self_pairs = [(names.index(a), names.index(b)) for a, b in node.get("self_pairs", [])]
        self.errors = None  # (n_rows, 4, 4) E_i of a calibrated model, None: the nominal chain
        by_row = {int(r): name for name, r in zip(self.joint_names, self.joint_row, strict=True)}
        self.row_keys = [by_row.get(i, f"row{i + 1}") for i in range(n)]  # an error-model file's name of each row

    def calibrated(self, doc: dict, where: str) -> BoomModel:
        """This boom with the error twists of an error-model file's ``doc`` (a copy; this one unchanged)."""
        if not isinstance(doc, dict) or doc.get("format") != "boom-ik/error-model/1":
            raise InputError(f"{where}: not a boom error model (format boom-ik/error-model/1)")
        for key, want in (("angle_unit", "deg"), ("length_unit", "mm"),
                          ("components", ["rx", "ry", "rz", "tx", "ty", "tz"])):
            if doc.get(key) != want:
                raise InputError(f"{where}: {key} = {doc.get(key)!r}; expected {want!r}")
        if doc.get("boom") != self.name:
            raise InputError(f"{where}: a model of boom {doc.get('boom')!r}, but this boom is a {self.name!r}")
        errors = doc.get("errors")
        if not isinstance(errors, dict) or set(errors) != set(self.row_keys):
            raise InputError(f"{where}: errors must list rows {self.row_keys}; found {errors!r}")
        xi = np.zeros((self.n_rows, 6))
        for i, key in enumerate(self.row_keys):
            row = errors[key]
            if not isinstance(row, dict) or set(row) != set(doc["components"]):
                raise InputError(f"{where}: errors.{key} must give {doc['components']}; got {row!r}")
            vals = [row[c] for c in doc["components"]]
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in vals):
                raise InputError(f"{where}: errors.{key}: every component must be a finite number; got {row!r}")
            xi[i] = np.array(vals, float) * np.array([math.pi / 180.0] * 3 + [1e-3] * 3)
        out = copy.copy(self)
        out.errors = np.stack([_error_transform(self.alpha[i], self.a[i], xi[i]) for i in range(self.n_rows)])
        return out

    def _body(self, name: str, node: dict, lng: float) -> Body:
        frames, offsets = [], []
        for end in ("start", "end"):
            f = node[end]["frame"]
            frames.append(self.n_rows if f == "tool" else int(f))
            along = np.array([0.0, 0.0, float(node[end].get("along_z", 0.0)) * lng])
            off = (self.tool if f == "tool" else np.zeros(3)) + along
            offsets.append(off)
        if not all(0 <= f <= self.n_rows for f in frames):
            raise InputError(f"{self.where}: body {name}: frame outside 0..{self.n_rows}")
        return Body(name, (frames[0], frames[1]), np.stack(offsets), float(node["radius"]) * lng,
                    float(node.get("tunnel_skip_end", 0.0)) * lng)

    def frames(self, q: np.ndarray) -> np.ndarray:
        """``(N, n_rows + 1, 4, 4)`` frames 0 (base, identity) .. n of joints ``q (N, n_joints)``."""
        N = q.shape[0]
        theta = np.broadcast_to(self.theta0, (N, self.n_rows)).copy()
        d = np.broadcast_to(self.d0, (N, self.n_rows)).copy()
        rev, pri = self.joint_row[self.revolute], self.joint_row[~self.revolute]
        theta[:, rev] += q[:, self.revolute]
        d[:, pri] += q[:, ~self.revolute]
        ca, sa = np.cos(self.alpha), np.sin(self.alpha)
        ct, st = np.cos(theta), np.sin(theta)
        T = np.zeros((N, self.n_rows, 4, 4))
        # RotX(alpha) TransX(a) RotZ(theta) TransZ(d), multiplied out (Craig eq. 3.6)
        T[..., 0, 0], T[..., 0, 1], T[..., 0, 3] = ct, -st, self.a
        T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = ca * st, ca * ct, -sa, -sa * d
        T[..., 2, 0], T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa * st, sa * ct, ca, ca * d
        T[..., 3, 3] = 1.0
        out = np.empty((N, self.n_rows + 1, 4, 4))
        out[:, 0] = np.eye(4)
        if self.errors is not None:
            T = self.errors @ T
        for i in range(self.n_rows):  # the chain's rows (8), not time: every instant at once
            out[:, i + 1] = out[:, i] @ T[:, i]
        return out

    def body_points(self, frames: np.ndarray) -> np.ndarray:
        """``(N, n_bodies, 2, 3)`` start and end of each body in the boom's base frame."""
        pts = []
        for b in self.bodies:
            ends = [frames[:, f, :3, :3] @ b.offsets[k] + frames[:, f, :3, 3] for k, f in enumerate(b.frames)]
            pts.append(np.stack(ends, 1))
        return np.stack(pts, 1)

    def tool_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Drill end H and drilling direction z of the tool frame, base frame, ``(N, 3)`` each."""
        f = self.frames(q)[:, -1]
        return f[:, :3, :3] @ self.tool + f[:, :3, 3], f[:, :3, 2]

    def lever(self, d_extent: np.ndarray | None = None) -> np.ndarray:
        """``(n_bodies, n_joints)``: a bound on how far any point of each body moves per rad (revolute)
        or per metre (prismatic) of each joint, in any configuration.

        A revolute joint j turns every later frame about its axis, which passes through frame j's
        origin, so a point p moves at most ``|p - o_j|`` per rad; ``|o_i - o_{i-1}| <= |a_{i-1}| +
        |d_i|`` bounds that sum link by link (``d_extent``: the largest ``|d_i|`` of each row over the
        joint ranges and the values met). A prismatic joint moves later points by the change itself.
        Interior points of a capsule move by a convex combination of its ends' motions.
        """
        if d_extent is None:
            d_extent = self.d_extent()
        link = np.abs(self.a) + d_extent  # bound of |o_i - o_{i-1}| for row i (0-based: frame i+1)
        if self.errors is not None:  # a calibrated row's error moves its origin by at most its translation
            link = link + np.linalg.norm(self.errors[:, :3, 3], axis=-1)
        out = np.zeros((len(self.bodies), len(self.joint_names)))
        for bi, b in enumerate(self.bodies):
            for k, f in enumerate(b.frames):
                reach_from = np.array([link[r + 1:f].sum() for r in range(self.n_rows)]) + np.linalg.norm(b.offsets[k])
                moved = self.joint_row < f  # joint on row r moves frames r+1 .. n
                per = np.where(self.revolute, reach_from[self.joint_row], 1.0) * moved
                out[bi] = np.maximum(out[bi], per)
        return out

    def d_extent(self, q_seen: np.ndarray | None = None) -> np.ndarray:
        """Largest ``|d_i|`` per D-H row over the prismatic ranges (and the values ``q_seen`` holds)."""
        ext = np.abs(self.d0).copy()
        for j in np.flatnonzero(~self.revolute):
            r = self.joint_row[j]
            vals = [self.lo[j], self.hi[j]]
            if q_seen is not None and len(q_seen):
                vals += [q_seen[:, j].min(), q_seen[:, j].max()]
            ext[r] = max(abs(self.d0[r] + v) for v in vals)
        return ext


def _expm(A: np.ndarray, terms: int = 24) -> np.ndarray:
    """The matrix exponential of a small square matrix: halve until its norm is below 1/2, sum the
    series, square back."""
    k = max(0, int(np.ceil(np.log2(max(np.abs(A).sum(1).max(), 1e-300) / 0.5))))
    B = A / 2.0**k
    out, term = np.eye(len(A)), np.eye(len(A))
    for i in range(1, terms):
        term = term @ B / i
        out = out + term
    for _ in range(k):
        out = out @ out
    return out


def _error_transform(alpha: float, a: float, xi: np.ndarray) -> np.ndarray:
    """``E = P exp(hat(xi)) P^-1`` (module docstring) of one row, ``(4, 4)``."""
    ca, sa = math.cos(alpha), math.sin(alpha)
    P = np.array([[1.0, 0, 0, a], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1]])
    rx, ry, rz, tx, ty, tz = xi
    hat = np.array([[0, -rz, ry, tx], [rz, 0, -rx, ty], [-ry, rx, 0, tz], [0, 0, 0, 0]], float)
    return P @ _expm(hat) @ np.linalg.inv(P)
