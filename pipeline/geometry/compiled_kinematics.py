"""The chain, its pose6 Jacobian and the four clearances once more, as numba kernels for one
configuration at a time.

Why a second copy: on one hole, torch spends about 4 us on every operation while the arithmetic of
the whole chain takes well under a microsecond (docs/benchmarks.md), so a rig asking for one hole at
a time waits on the framework. These kernels do the same arithmetic in compiled loops. They are
built from the same :class:`Boom` and :class:`SafetyModel` objects (no number copied by hand), and
tests/test_compiled.py holds them equal to the torch versions (reference vectors, random joints,
Jacobians, clearances) at float64 rounding level, so the two cannot drift apart.

Layout: :class:`ChainArrays` and :class:`SafetyArrays` turn the objects into plain arrays once; the
``@njit`` functions take those arrays and preallocated outputs, so a solver's inner loop allocates
nothing. Every kernel is compiled with ``cache=True`` (compiled once per machine, then loaded).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit

from pipeline.core.errors import InputError
from pipeline.geometry.collision import SAFETY_KINDS, SafetyModel
from pipeline.geometry.kinematics import JOINT_PARAMS, Boom
from pipeline.geometry.tunnel import SURFACES

EPS64 = float(np.finfo(np.float64).eps)


def nominal_chain(boom: Boom) -> bool:
    """Whether ``boom``'s frames are :class:`Boom`'s own D-H chain (no override of its link
    transforms, such as a calibrated boom's error twists): what the kernels compute."""
    return type(boom).link_transforms is Boom.link_transforms and type(boom).frames is Boom.frames


NO_ERRORS = np.zeros((0, 4, 4))  # the nominal chain's error transforms: none


def chain_and_errors(boom: Boom) -> tuple[Boom, np.ndarray] | None:
    """What the rig kernels compute for ``boom``: its nominal D-H boom and the constant rigid transforms
    ``E (R, 4, 4)`` that premultiply its links (:func:`frames_into`), :data:`NO_ERRORS` for the
    nominal chain; None for a chain of any other kind. A calibrated boom is read through the interface
    of :class:`~pipeline.calibration.error_model.BoomWithErrors` (``nominal``, ``error_transforms()``),
    which lives above this layer; :meth:`pipeline.geometry.compiled_rig.CompiledBoom.for_boom` checks
    the kernel's frames against the boom's own before they are used."""
    if nominal_chain(boom):
        return boom, NO_ERRORS
    nominal, errors = getattr(boom, "nominal", None), getattr(boom, "error_transforms", None)
    if not (isinstance(nominal, Boom) and nominal_chain(nominal) and callable(errors)
            and type(boom).frames is Boom.frames):
        return None
    E = np.ascontiguousarray(errors(torch.float64).detach().cpu().numpy(), dtype=np.float64)
    rigid = E.shape == (nominal.n_rows, 4, 4) and bool((E[:, 3] == np.array([0.0, 0.0, 0.0, 1.0])).all())
    return (nominal, E) if rigid else None


@dataclass(frozen=True)
class ChainArrays:
    """A :class:`Boom` as arrays: D-H rows, which parameter of which row each joint drives, the
    tool offset, and per joint where its axis lives (:meth:`Boom._axis_layout`'s rule)."""

    rows: np.ndarray  # (R, 4) alpha, a, theta, d
    cos_alpha: np.ndarray  # (R,) as torch computes them (the chain's constants)
    sin_alpha: np.ndarray
    modified: bool
    joint_row: np.ndarray  # (n,) int64
    joint_param: np.ndarray  # (n,) int64: index into JOINT_PARAMS
    tool: np.ndarray  # (3,)
    axis_frame: np.ndarray  # (n,) frame index holding the joint's axis
    along_x: np.ndarray  # (n,) bool: the axis is that frame's x (an ``a`` joint), else its z
    revolute: np.ndarray  # (n,) bool
    moves: np.ndarray  # (n,) first frame index the joint moves
    depth: float  # preview depth D (m); 0 for a boom without one (its preview rows repeat the collar's)

    @classmethod
    def from_boom(cls, boom: Boom) -> ChainArrays:
        if not nominal_chain(boom):
            raise InputError(f"boom '{boom.name}' ({type(boom).__name__}): its frames are not the D-H chain of its "
                             "rows (a calibrated model's error twists?), and the compiled kernels know only that "
                             "chain; use the torch solver (hybrid) for it")
        modified = boom.convention == "modified"
        frame = [j.row if (j.param == "a") == modified else j.row + 1 for j in boom.joints]
        rows = np.array(boom.rows, dtype=np.float64).reshape(boom.n_rows, 4)
        return cls(
            rows=rows,
            cos_alpha=torch.cos(torch.from_numpy(rows[:, 0])).numpy().copy(),
            sin_alpha=torch.sin(torch.from_numpy(rows[:, 0])).numpy().copy(),
            modified=modified,
            joint_row=np.array([j.row for j in boom.joints], dtype=np.int64),
            joint_param=np.array([JOINT_PARAMS.index(j.param) for j in boom.joints], dtype=np.int64),
            tool=np.array(boom.tool, dtype=np.float64),
            axis_frame=np.array(frame, dtype=np.int64),
            along_x=np.array([j.param == "a" for j in boom.joints]),
            revolute=np.array([j.revolute for j in boom.joints]),
            moves=np.array([j.row + 1 for j in boom.joints], dtype=np.int64),
            depth=float(boom.preview_depth or 0.0),
        )

    @property
    def n_frames(self) -> int:
        return self.rows.shape[0] + 2

    def args(self) -> tuple:
        """The arrays in the order every chain kernel takes them."""
        return (self.rows, self.cos_alpha, self.sin_alpha, self.modified, self.joint_row, self.joint_param, self.tool,
                self.axis_frame, self.along_x, self.revolute, self.moves, self.depth)


@dataclass(frozen=True)
class SafetyArrays:
    """A :class:`SafetyModel` as arrays: capsule end points (frame, offset along its z), radii,
    the untested front length, self pairs, safety distances and the tunnel's outline."""

    end_frame: np.ndarray  # (2 * bodies,) start, end of each body
    end_along: np.ndarray  # (2 * bodies,)
    radius: np.ndarray  # (bodies,)
    skip: np.ndarray  # (bodies,)
    pairs: np.ndarray  # (pairs, 2) int64 body indices
    d_self: float
    surface: np.ndarray  # (3,) wall, ground, arch safety distances
    half_width: float
    wall_height: float
    t: np.ndarray  # (points,) sample fractions along each capsule, the same values as SafetyModel's
    exact: bool  # also the exact check's candidate points (SafetyModel.exact)
    outline: np.ndarray  # (segments, 7) a profile's segments (Profile.outline_array); (0, 7): the horseshoe

    @classmethod
    def from_model(cls, safety: SafetyModel) -> SafetyArrays:
        bodies = list(safety.boom.bodies.values())
        names = [b.name for b in bodies]
        return cls(
            end_frame=np.array([p.frame for b in bodies for p in (b.start, b.end)], dtype=np.int64),
            end_along=np.array([p.along_z for b in bodies for p in (b.start, b.end)], dtype=np.float64),
            radius=np.array([b.radius for b in bodies], dtype=np.float64),
            skip=np.array([b.tunnel_skip_end for b in bodies], dtype=np.float64),
            pairs=np.array([(names.index(a), names.index(b)) for a, b in safety.boom.self_pairs],
                           dtype=np.int64).reshape(-1, 2),
            d_self=float(safety.distances.self),
            surface=np.array([getattr(safety.distances, k) for k in SURFACES], dtype=np.float64),
            half_width=float(getattr(safety.tunnel, "half_width", 0.0)),  # horseshoe only (outline empty)
            wall_height=float(getattr(safety.tunnel, "wall_height", 0.0)),
            # torch's linspace, not numpy's: the two may differ in the last bit
            t=torch.linspace(0.0, 1.0, safety.points_per_capsule, dtype=torch.float64).numpy().copy(),
            exact=bool(safety.exact),
            outline=(safety.tunnel.outline_array() if safety.tunnel.kind == "profile" else np.zeros((0, 7))),
        )

    def args(self) -> tuple:
        return (self.end_frame, self.end_along, self.radius, self.skip, self.pairs, self.d_self, self.surface,
                self.half_width, self.wall_height, self.t, self.exact, self.outline)


assert SAFETY_KINDS == ("self", "wall", "ground", "arch")  # the kernels' clearance order


# ---------------------------------------------------------------------------------------------- chain
@njit(cache=True)
def _link(k, q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param):
    """The top three rows of D-H row ``k``'s link transform at joints ``q`` (its last row is 0, 0, 0, 1)."""
    a, theta, d = rows[k, 1], rows[k, 2], rows[k, 3]
    for j in range(joint_row.shape[0]):
        if joint_row[j] == k:
            if joint_param[j] == 0:
                theta += q[j]
            elif joint_param[j] == 1:
                d += q[j]
            else:
                a += q[j]
    ct, st, ca, sa = math.cos(theta), math.sin(theta), cos_alpha[k], sin_alpha[k]
    if modified:
        return (ct, -st, 0.0, a,
                st * ca, ct * ca, -sa, -d * sa,
                st * sa, ct * sa, ca, d * ca)
    return (ct, -st * ca, st * sa, a * ct,
            st, ct * ca, -ct * sa, a * st,
            0.0, sa, ca, d)


@njit(cache=True)
def _times_link(P, N, link):
    """``N = P @ L``, L's last row being (0, 0, 0, 1)."""
    l00, l01, l02, l03, l10, l11, l12, l13, l20, l21, l22, l23 = link
    for i in range(4):
        p0, p1, p2, p3 = P[i, 0], P[i, 1], P[i, 2], P[i, 3]
        N[i, 0] = p0 * l00 + p1 * l10 + p2 * l20
        N[i, 1] = p0 * l01 + p1 * l11 + p2 * l21
        N[i, 2] = p0 * l02 + p1 * l12 + p2 * l22
        N[i, 3] = p0 * l03 + p1 * l13 + p2 * l23 + p3


@njit(cache=True)
def _identity(B):
    for i in range(4):
        for j in range(4):
            B[i, j] = 1.0 if i == j else 0.0


@njit(cache=True)
def _tool_frame(last, tool, out):
    """The tool frame: ``last`` with its origin moved by ``tool`` along its axes."""
    for i in range(3):
        for j in range(3):
            out[i, j] = last[i, j]
        out[i, 3] = last[i, 0] * tool[0] + last[i, 1] * tool[1] + last[i, 2] * tool[2] + last[i, 3]
    for j in range(4):
        out[3, j] = last[3, j]


@njit(cache=True)
def _error_times_link(E, link):
    """``E @ L`` of a rigid error transform and a link (last rows 0, 0, 0, 1), as :func:`_link` gives a link."""
    l00, l01, l02, l03, l10, l11, l12, l13, l20, l21, l22, l23 = link
    return (E[0, 0] * l00 + E[0, 1] * l10 + E[0, 2] * l20, E[0, 0] * l01 + E[0, 1] * l11 + E[0, 2] * l21,
            E[0, 0] * l02 + E[0, 1] * l12 + E[0, 2] * l22, E[0, 0] * l03 + E[0, 1] * l13 + E[0, 2] * l23 + E[0, 3],
            E[1, 0] * l00 + E[1, 1] * l10 + E[1, 2] * l20, E[1, 0] * l01 + E[1, 1] * l11 + E[1, 2] * l21,
            E[1, 0] * l02 + E[1, 1] * l12 + E[1, 2] * l22, E[1, 0] * l03 + E[1, 1] * l13 + E[1, 2] * l23 + E[1, 3],
            E[2, 0] * l00 + E[2, 1] * l10 + E[2, 2] * l20, E[2, 0] * l01 + E[2, 1] * l11 + E[2, 2] * l21,
            E[2, 0] * l02 + E[2, 1] * l12 + E[2, 2] * l22, E[2, 0] * l03 + E[2, 1] * l13 + E[2, 2] * l23 + E[2, 3])


@njit(cache=True)
def frames_into(q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, F):
    """Every frame of the chain at joints ``q (n,)`` into ``F (R + 2, 4, 4)``: the base, one per
    D-H row, the tool (as :meth:`Boom.frames`). ``errors``: :data:`NO_ERRORS` for the nominal chain, or a
    calibrated boom's error transforms ``(R, 4, 4)``, rigid, whose links are ``E_k @ L_k``
    (:class:`pipeline.calibration.error_model.BoomWithErrors`)."""
    R = rows.shape[0]
    _identity(F[0])
    for k in range(R):
        link = _link(k, q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param)
        if errors.shape[0] > 0:
            link = _error_times_link(errors[k], link)
        _times_link(F[k], F[k + 1], link)
    _tool_frame(F[R], tool, F[R + 1])


@njit(cache=True)
def pose6_jacobian_into(F, depth, axis_frame, along_x, revolute, pose, J):
    """``pose (6,) = [p, p + D z]`` of the tool frame and ``J (6, n) = d pose6 / d q`` (the
    geometric Jacobian of the collar, then the preview rows ``J_p + D (w x z)``)."""
    T = F[F.shape[0] - 1]
    n = axis_frame.shape[0]
    for i in range(3):
        pose[i] = T[i, 3]
        pose[3 + i] = T[i, 3] + depth * T[i, 2]
    z0, z1, z2 = T[0, 2], T[1, 2], T[2, 2]
    for j in range(n):
        f = F[axis_frame[j]]
        c = 0 if along_x[j] else 2
        u0, u1, u2 = f[0, c], f[1, c], f[2, c]
        if revolute[j]:
            d0, d1, d2 = pose[0] - f[0, 3], pose[1] - f[1, 3], pose[2] - f[2, 3]
            l0, l1, l2 = u1 * d2 - u2 * d1, u2 * d0 - u0 * d2, u0 * d1 - u1 * d0
            t0, t1, t2 = u1 * z2 - u2 * z1, u2 * z0 - u0 * z2, u0 * z1 - u1 * z0
        else:
            l0, l1, l2 = u0, u1, u2
            t0, t1, t2 = 0.0, 0.0, 0.0
        J[0, j], J[1, j], J[2, j] = l0, l1, l2
        J[3, j], J[4, j], J[5, j] = l0 + depth * t0, l1 + depth * t1, l2 + depth * t2


@njit(cache=True)
def _point_jacobian(F, p, frame, axis_frame, along_x, revolute, moves, out):
    """Linear Jacobian ``out (3, n)`` of the point ``p`` fixed to frame index ``frame``."""
    for j in range(axis_frame.shape[0]):
        if moves[j] > frame:
            out[0, j] = out[1, j] = out[2, j] = 0.0
            continue
        f = F[axis_frame[j]]
        c = 0 if along_x[j] else 2
        u0, u1, u2 = f[0, c], f[1, c], f[2, c]
        if revolute[j]:
            d0, d1, d2 = p[0] - f[0, 3], p[1] - f[1, 3], p[2] - f[2, 3]
            out[0, j], out[1, j], out[2, j] = u1 * d2 - u2 * d1, u2 * d0 - u0 * d2, u0 * d1 - u1 * d0
        else:
            out[0, j], out[1, j], out[2, j] = u0, u1, u2


# ---------------------------------------------------------------------------------------------- tunnel
@njit(cache=True)
def _signed_hypot(u, v, sign_of):
    h = math.sqrt(u * u + v * v)
    return -h if sign_of < 0 else h


@njit(cache=True)
def surface_distances(y, z, r, h):
    """Signed distance of ``(y, z)`` to the wall, the ground and the arch (:class:`Horseshoe`)."""
    inward = r - abs(y)
    if z > h:
        return _signed_hypot(inward, z - h, inward), z, r - math.sqrt(y * y + (z - h) * (z - h))
    return inward, z, _signed_hypot(inward, h - z, inward)


@njit(cache=True)
def surface_gradient(kind, y, z, r, h):
    """``(d/dy, d/dz)`` of surface ``kind`` (0 wall, 1 ground, 2 arch) at ``(y, z)``, in closed
    form (:meth:`Horseshoe.surface_gradients`)."""
    if kind == 1:
        return 0.0, 1.0
    side = -1.0 if y < 0 else 1.0
    inward = r - abs(y)
    above = z > h
    corner = max(math.sqrt(inward * inward + (z - h) * (z - h)), 1e-12)
    sign = -1.0 if inward < 0 else 1.0
    corner_dy, corner_dz = -side * inward * sign / corner, (z - h) * sign / corner
    if kind == 0:
        return (corner_dy, corner_dz) if above else (-side, 0.0)
    radial = max(math.sqrt(y * y + (z - h) * (z - h)), 1e-12)
    return (-y / radial, -(z - h) / radial) if above else (corner_dy, corner_dz)


@njit(cache=True)
def _closest_params(a, b, c, e, f):
    """Where the closest points of two segments ``p1 + s d1`` and ``p2 + t d2`` lie (``s, t`` in [0, 1]), from
    ``a = d1.d1, b = d1.d2, c = d1.r, e = d2.d2, f = d2.r`` (``r = p1 - p2``): clamped (Ericson 5.1.9), the
    branches of :func:`pipeline.geometry.collision.segment_distance`, for 3-D segments and the plane alike."""
    eps = 1e-12
    denom = a * e - b * b
    a_ok, e_ok = a > eps, e > eps
    a_safe = a if a_ok else 1.0
    e_safe = e if e_ok else 1.0
    s = (b * f - c * e) / denom if denom > 64 * EPS64 * a * e else 0.0
    s = min(max(s, 0.0), 1.0)
    t = (b * s + f) / e_safe
    if t < 0:
        s = min(max(-c / a_safe, 0.0), 1.0)
    elif t > 1:
        s = min(max((b - c) / a_safe, 0.0), 1.0)
    t = min(max(t, 0.0), 1.0)
    if a_ok and not e_ok:
        s = min(max(-c / a_safe, 0.0), 1.0)
    if not e_ok:
        t = 0.0
    if not a_ok and e_ok:
        t = min(max(f / e_safe, 0.0), 1.0)
    if not a_ok:
        s = 0.0
    return s, t


# ---------------------------------------------------------------------------------------------- profile
PROFILE_TIE = 1e-9  # as pipeline.geometry.profile.TIE
# A tunnel of any cross-section (pipeline.geometry.profile.Profile): ``outline (segments, 7)`` holds each
# segment's y0, z0, y1, z1, kind (0 wall, 1 ground, 2 arch) and inward normal; the same rule as the torch
# model's, loop by loop.
@njit(cache=True)
def _inside(y, z, outline):
    """Even-odd rule: (y, z) inside the profile's polygon."""
    inside = False
    for i in range(outline.shape[0]):
        y0, z0, y1, z1 = outline[i, 0], outline[i, 1], outline[i, 2], outline[i, 3]
        if (z0 > z) != (z1 > z) and y < y0 + (z - z0) * (y1 - y0) / (z1 - z0):
            inside = not inside
    return inside


@njit(cache=True)
def _to_segment(y, z, outline, i):
    """Distance from (y, z) to segment ``i`` and its nearest point there."""
    y0, z0 = outline[i, 0], outline[i, 1]
    dy, dz = outline[i, 2] - y0, outline[i, 3] - z0
    s = min(max(((y - y0) * dy + (z - z0) * dz) / (dy * dy + dz * dz), 0.0), 1.0)
    py, pz = y0 + s * dy, z0 + s * dz
    return math.sqrt((y - py) * (y - py) + (z - pz) * (z - pz)), py, pz


@njit(cache=True)
def _nearest_of_kinds(y, z, outline, D, SEG):
    """Per kind, the distance from (y, z) to its nearest segment into ``D (3,)`` and that segment into
    ``SEG (3,)``; returns the distance to the nearest segment of all."""
    for k in range(3):
        D[k] = np.inf
        SEG[k] = -1
    for i in range(outline.shape[0]):
        k = int(outline[i, 4])
        d, _, _ = _to_segment(y, z, outline, i)
        if d < D[k]:
            D[k], SEG[k] = d, i
    return min(D[0], min(D[1], D[2]))


@njit(cache=True)
def _segment_distance_2d(ay, az, by, bz, outline, i):
    """Clamped distance between segment (ay, az)-(by, bz) and outline segment ``i``, and where it is
    reached along the first: the branches of :func:`segment_distance` in the plane."""
    d1y, d1z = by - ay, bz - az
    d2y, d2z = outline[i, 2] - outline[i, 0], outline[i, 3] - outline[i, 1]
    ry, rz = ay - outline[i, 0], az - outline[i, 1]
    s, t = _closest_params(d1y * d1y + d1z * d1z, d1y * d2y + d1z * d2z, d1y * ry + d1z * rz,
                           d2y * d2y + d2z * d2z, d2y * ry + d2z * rz)
    gy = (ay + s * d1y) - (outline[i, 0] + t * d2y)
    gz = (az + s * d1z) - (outline[i, 1] + t * d2z)
    return math.sqrt(gy * gy + gz * gz), s


@njit(cache=True)
def profile_capsule_into(y0, z0, dy, dz, outline, V, FR, D, SEG):
    """The distance of the axis ``(y0, z0) + u (dy, dz)`` to each kind into ``V (3,)`` and where along it
    into ``FR (3,)`` (:meth:`Profile.capsule_distances`): the least segment-segment distance per kind,
    then each end outside the profile at its negative depth for the kind nearest to it."""
    for k in range(3):
        V[k] = np.inf
        FR[k] = 0.0
    for i in range(outline.shape[0]):
        k = int(outline[i, 4])
        d, s = _segment_distance_2d(y0, z0, y0 + dy, z0 + dz, outline, i)
        if d < V[k]:
            V[k], FR[k] = d, s
    for u in (0.0, 1.0):
        y, z = y0 + u * dy, z0 + u * dz
        if not _inside(y, z, outline):
            nearest = _nearest_of_kinds(y, z, outline, D, SEG)
            for k in range(3):
                if D[k] <= nearest + PROFILE_TIE and -D[k] < V[k]:
                    V[k], FR[k] = -D[k], u


@njit(cache=True)
def profile_gradient(kind, y, z, outline, D, SEG):
    """``(d/dy, d/dz)`` of the point's signed distance to ``kind`` (:meth:`Profile.surface_gradients`):
    the unit vector from the kind's nearest point, negative for a point outside whose nearest kind it
    is; on a segment, that segment's inward normal."""
    nearest = _nearest_of_kinds(y, z, outline, D, SEG)
    i = SEG[kind]
    d, py, pz = _to_segment(y, z, outline, i)
    sign = -1.0 if (D[kind] <= nearest + PROFILE_TIE and not _inside(y, z, outline)) else 1.0
    if d > 1e-12:
        return sign * (y - py) / d, sign * (z - pz) / d
    return sign * outline[i, 5], sign * outline[i, 6]


# ---------------------------------------------------------------------------------------------- clearances
EXACT_CANDIDATES = 6  # as pipeline.geometry.collision.EXACT_CANDIDATES


@njit(cache=True)
def _crossing(v0, dv, level):
    if abs(dv) > 1e-15:
        u = (level - v0) / dv
        if 0.0 < u < 1.0:
            return u
    return 0.0


@njit(cache=True)
def _projection(cy, y0, z0, dy, dz, h):
    dd = dy * dy + dz * dz
    if dd > 1e-24:
        return min(max(((cy - y0) * dy + (h - z0) * dz) / dd, 0.0), 1.0)
    return 0.0


@njit(cache=True)
def exact_fractions_into(y0, z0, dy, dz, r, h, U):
    """The exact check's candidate fractions along the checked axis ``(y0, z0) + u (dy, dz)`` into
    ``U (6,)``, in the order and by the rule of :meth:`SafetyModel._fractions`."""
    U[0], U[1] = 0.0, 1.0
    U[2], U[3] = _crossing(z0, dz, h), _crossing(y0, dy, 0.0)
    U[4], U[5] = _projection(r, y0, z0, dy, dz, h), _projection(-r, y0, z0, dy, dz, h)


@njit(cache=True)
def _ends(F, end_frame, end_along, E):
    for e in range(end_frame.shape[0]):
        f = F[end_frame[e]]
        for i in range(3):
            E[e, i] = f[i, 3] + end_along[e] * f[i, 2] if end_along[e] != 0.0 else f[i, 3]


@njit(cache=True)
def segment_distance(p1, q1, p2, q2):
    """Clamped segment-segment distance ``(d, s, t)`` (Ericson 5.1.9), the same branches as
    :func:`pipeline.geometry.collision.segment_distance`."""
    d1 = q1 - p1
    d2 = q2 - p2
    rr = p1 - p2
    s, t = _closest_params(d1[0] * d1[0] + d1[1] * d1[1] + d1[2] * d1[2], d1[0] * d2[0] + d1[1] * d2[1] + d1[2] * d2[2],
                           d1[0] * rr[0] + d1[1] * rr[1] + d1[2] * rr[2], d2[0] * d2[0] + d2[1] * d2[1] + d2[2] * d2[2],
                           d2[0] * rr[0] + d2[1] * rr[1] + d2[2] * rr[2])
    g0 = (p1[0] + s * d1[0]) - (p2[0] + t * d2[0])
    g1 = (p1[1] + s * d1[1]) - (p2[1] + t * d2[1])
    g2 = (p1[2] + s * d1[2]) - (p2[2] + t * d2[2])
    return math.sqrt(g0 * g0 + g1 * g1 + g2 * g2), s, t


@njit(cache=True)
def clearances_into(F, end_frame, end_along, radius, skip, pairs, d_self, surface, half_width, wall_height, t,
                    exact, outline, out, arg, frac_at, E):
    """The four clearances (self, wall, ground, arch; m, negative = violated) of frames ``F`` into
    ``out (4,)``, as :meth:`SafetyModel.clearances_from_frames`. Also where each tunnel minimum lies:
    ``arg[k]`` the sample index (body * points + point) and ``frac_at[k]`` its fraction along its
    body; for self, ``arg`` holds the pair index and ``frac_at`` is unused (gradients need these).
    ``E (2 * bodies, 3)``: scratch, left holding the capsules' end points. ``exact``: after the samples
    ``t``, the exact check's candidate points (:func:`exact_fractions_into`), as :class:`SafetyModel`.
    A profile (``outline`` not empty) measures each axis whole (:func:`profile_capsule_into`): ``arg`` is
    then the body."""
    S = t.shape[0]
    profile = outline.shape[0] > 0
    nb, P = radius.shape[0], 1 if profile else S + (EXACT_CANDIDATES if exact else 0)
    U = np.zeros(EXACT_CANDIDATES)
    V, FR, D, SEG = np.empty(3), np.empty(3), np.empty(3), np.empty(3, dtype=np.int64)
    _ends(F, end_frame, end_along, E)
    for k in range(3):
        out[1 + k] = np.inf
    for b in range(nb):
        s0, s1, s2 = E[2 * b, 0], E[2 * b, 1], E[2 * b, 2]
        a0, a1, a2 = E[2 * b + 1, 0] - s0, E[2 * b + 1, 1] - s1, E[2 * b + 1, 2] - s2
        keep = 1.0
        if skip[b] > 0:
            keep = max(1.0 - skip[b] / max(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2), 1e-12), 0.0)
        if profile:
            profile_capsule_into(s1, s2, keep * a1, keep * a2, outline, V, FR, D, SEG)
            for k in range(3):
                v = V[k] - radius[b] - surface[k]
                if v < out[1 + k]:
                    out[1 + k], arg[1 + k], frac_at[1 + k] = v, b, FR[k] * keep
            continue
        if exact:
            exact_fractions_into(s1, s2, keep * a1, keep * a2, half_width, wall_height, U)
        for i in range(P):
            fr = (t[i] if i < S else U[i - S]) * keep
            y, z = s1 + fr * a1, s2 + fr * a2
            w, g, ar = surface_distances(y, z, half_width, wall_height)
            vals = (w - radius[b] - surface[0], g - radius[b] - surface[1], ar - radius[b] - surface[2])
            for k in range(3):
                if vals[k] < out[1 + k]:
                    out[1 + k], arg[1 + k], frac_at[1 + k] = vals[k], b * P + i, fr
    out[0] = np.inf
    arg[0] = -1
    for m in range(pairs.shape[0]):
        ia, ib = pairs[m, 0], pairs[m, 1]
        dist, s, tt = segment_distance(E[2 * ia], E[2 * ia + 1], E[2 * ib], E[2 * ib + 1])
        c = dist - radius[ia] - radius[ib] - d_self
        if arg[0] < 0 or c < out[0]:
            out[0], arg[0] = c, m
    # the self pair's closest points are needed for its gradient: recomputed there (one pair on jumbo8)


@njit(cache=True)
def clearance_jacobians_into(F, end_frame, end_along, radius, skip, pairs, d_self, surface, half_width, wall_height,
                             t, exact, outline, axis_frame, along_x, revolute, moves, out, G):
    """The clearances into ``out (4,)`` and their gradients with respect to the joints into ``G (4, n)``
    (:meth:`SafetyModel.clearances_with_jacobians`): a tunnel clearance's gradient is the surface
    normal at its minimising sample point times that point's Jacobian, self's the unit vector between
    the closest points times their relative Jacobian."""
    profile = outline.shape[0] > 0
    nb, n = radius.shape[0], axis_frame.shape[0]
    P = 1 if profile else t.shape[0] + (EXACT_CANDIDATES if exact else 0)
    arg = np.empty(4, dtype=np.int64)
    frac = np.empty(4)
    E = np.empty((2 * nb, 3))
    D, SEG = np.empty(3), np.empty(3, dtype=np.int64)
    clearances_into(F, end_frame, end_along, radius, skip, pairs, d_self, surface, half_width, wall_height, t,
                    exact, outline, out, arg, frac, E)
    J0, J1 = np.empty((3, n)), np.empty((3, n))
    for k in range(1, 4):
        b = arg[k] // P
        _point_jacobian(F, E[2 * b], end_frame[2 * b], axis_frame, along_x, revolute, moves, J0)
        _point_jacobian(F, E[2 * b + 1], end_frame[2 * b + 1], axis_frame, along_x, revolute, moves, J1)
        fr = frac[k]
        y = E[2 * b, 1] + fr * (E[2 * b + 1, 1] - E[2 * b, 1])
        z = E[2 * b, 2] + fr * (E[2 * b + 1, 2] - E[2 * b, 2])
        if profile:
            gy, gz = profile_gradient(k - 1, y, z, outline, D, SEG)
        else:
            gy, gz = surface_gradient(k - 1, y, z, half_width, wall_height)
        for j in range(n):
            G[k, j] = (gy * ((1 - fr) * J0[1, j] + fr * J1[1, j])
                       + gz * ((1 - fr) * J0[2, j] + fr * J1[2, j]))
    if arg[0] < 0:  # no self pairs: self collision cannot happen
        for j in range(n):
            G[0, j] = 0.0
        return
    ia, ib = pairs[arg[0], 0], pairs[arg[0], 1]
    _, s, tt = segment_distance(E[2 * ia], E[2 * ia + 1], E[2 * ib], E[2 * ib + 1])
    gap = np.empty(3)
    for i in range(3):
        gap[i] = (E[2 * ia, i] + s * (E[2 * ia + 1, i] - E[2 * ia, i])
                  - (E[2 * ib, i] + tt * (E[2 * ib + 1, i] - E[2 * ib, i])))
    norm = max(math.sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]), 1e-12)
    Ja0, Ja1, Jb0, Jb1 = np.empty((3, n)), np.empty((3, n)), np.empty((3, n)), np.empty((3, n))
    _point_jacobian(F, E[2 * ia], end_frame[2 * ia], axis_frame, along_x, revolute, moves, Ja0)
    _point_jacobian(F, E[2 * ia + 1], end_frame[2 * ia + 1], axis_frame, along_x, revolute, moves, Ja1)
    _point_jacobian(F, E[2 * ib], end_frame[2 * ib], axis_frame, along_x, revolute, moves, Jb0)
    _point_jacobian(F, E[2 * ib + 1], end_frame[2 * ib + 1], axis_frame, along_x, revolute, moves, Jb1)
    for j in range(n):
        g = 0.0
        for i in range(3):
            g += gap[i] / norm * ((1 - s) * Ja0[i, j] + s * Ja1[i, j] - (1 - tt) * Jb0[i, j] - tt * Jb1[i, j])
        G[0, j] = g


# ---------------------------------------------------------------------------------------------- batched views
@njit(cache=True)
def batch_pose6_jacobian(Q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, axis_frame, along_x,
                         revolute, moves, depth):
    """Frames ``(B, R + 2, 4, 4)``, pose6 ``(B, 6)`` and its Jacobian ``(B, 6, n)`` of joints ``Q (B, n)``
    (for tests and callers outside a solver loop)."""
    B, n = Q.shape
    Fs = np.empty((B, rows.shape[0] + 2, 4, 4))
    pose, J = np.empty((B, 6)), np.empty((B, 6, n))
    for b in range(B):
        frames_into(Q[b], rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, NO_ERRORS, Fs[b])
        pose6_jacobian_into(Fs[b], depth, axis_frame, along_x, revolute, pose[b], J[b])
    return Fs, pose, J


@njit(cache=True)
def batch_clearances(Fs, end_frame, end_along, radius, skip, pairs, d_self, surface, half_width, wall_height, t,
                     exact, outline, axis_frame, along_x, revolute, moves):
    """Clearances ``(B, 4)`` and their gradients ``(B, 4, n)`` of frames ``Fs (B, R + 2, 4, 4)``."""
    B, n = Fs.shape[0], axis_frame.shape[0]
    C, G = np.empty((B, 4)), np.empty((B, 4, n))
    for b in range(B):
        clearance_jacobians_into(Fs[b], end_frame, end_along, radius, skip, pairs, d_self, surface, half_width,
                                 wall_height, t, exact, outline, axis_frame, along_x, revolute, moves, C[b], G[b])
    return C, G


def chain_values(chain: ChainArrays, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames, pose6 and pose6 Jacobian of joints ``q (B, n)`` through the kernels."""
    return batch_pose6_jacobian(np.ascontiguousarray(q, dtype=np.float64), *chain.args())


def clearance_values(chain: ChainArrays, safety: SafetyArrays, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clearances ``(B, 4)`` in :data:`SAFETY_KINDS` order and their joint gradients ``(B, 4, n)``."""
    return batch_clearances(np.ascontiguousarray(frames), *safety.args(), chain.axis_frame, chain.along_x,
                            chain.revolute, chain.moves)
