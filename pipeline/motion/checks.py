"""Dense clearance check of one boom's timed motion in a rig (docs/reference.md section 7: moves are collision-free).

At every checked instant the boom's self and tunnel clearances (its :class:`~pipeline.geometry.
collision.SafetyModel`, the tunnel seen from its base through :class:`~pipeline.geometry.rig.
MountedBoom`) and its boom-boom clearance to every other boom (:class:`~pipeline.geometry.boom_pair.
BoomPair`, d_boom) are computed, the other booms standing or moving along their own timed paths,
evaluated at the same instants. All instants of a move go through the kinematics and the clearances
as one batch.

Check step. For a joint step ``dq`` every boom point moves by at most ``sum_i r_i |dq_i|``: a point
``p`` beyond joint ``i`` moves, per unit of that joint, by ``|u_i x (p - o_i)| <= |p - o_i|``
(revolute, ``o_i`` a point on the axis ``u_i``) or by 1 (prismatic), and :func:`lever_arms` gives
``r_i >= |p - o_i|`` for every capsule point in every configuration within the joint ranges (the
triangle inequality over the D-H rows from joint i's axis frame to the point, each row's offset at
its largest over the joint ranges). Integrating the point's speed ``sum_i J_i dq_i/dt`` along any
motion gives the bound. Instants are chosen so that this bound is at most ``resolution`` (1 cm) for
this boom and for each moving other between two consecutive instants (the union of each boom's own
instants), so no point of any boom moves more than 1 cm between two checks.

A motion is clear when every clearance is >= 0 at every checked instant. Between two checks ``k``,
``k+1`` a clearance can dip below them, but not far: with ``L_k`` the interval's drift bound (this
boom's travel bound for the tunnel, twice it for self, its own plus the other's for boom-boom: each
point of a distance moves at most its boom's travel), the clearance anywhere in the interval is at
least ``(c_k + c_{k+1} - L_k) / 2`` (it is within ``L x`` of ``c_k`` after a share ``x`` of the
travel, and within ``L (1 - x)`` of ``c_{k+1}``). :attr:`Clearance.floor` is the smallest such bound
over the motion: a certified lower bound of the smallest clearance at *every* instant, not only the
checked ones (it needs straight motion between instants, which the instants of a :class:`Path` and
of a :class:`Timed` path's rows give).

Acceptance. A motion is taken (by :func:`pipeline.motion.moves.plan_move` and the round's move book)
only when each kind's floor (:attr:`Clearance.floors`: self, tunnel, boom) is at least its margin
(:func:`margins`). The floor's gap below the samples shrinks with the resolution, so where every
sample keeps its margin but a floor does not, :func:`certify_path` and :func:`certify_straight_moves`
check again at half the resolution, up to :data:`REFINEMENTS` times.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import torch

from pipeline.core.errors import InputError
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rig import Rig
from pipeline.geometry.tunnel import SURFACES
from pipeline.motion.path import Path, Timed, distinct, travel

RESOLUTION = 0.01  # m: no boom point moves more than this between two checks
REFINEMENTS = 4  # halvings of the resolution tried where a floor is short of its margin (16x denser at most)
KINDS = ("self", "tunnel", "boom")  # the kinds of clearance a floor and a margin are given for


def margins(tolerance: float, others_move: bool = False, self_m: float = 0.0, tunnel_m: float = 0.0
            ) -> dict[str, float]:
    """The certified floor each kind must keep so that the trajectory file is clear too, plus any
    extra ``self_m``, ``tunnel_m`` (m) a caller asks for.

    The file's rows lie on the planned joint-space segments (:meth:`pipeline.motion.path.Path.rows`:
    both sides are ``start + s step``, rows at every waypoint), so linear interpolation between rows
    passes through the plan's own configurations, only at other times. A boom's self and tunnel
    clearances, and its distance to a boom *standing* still, depend on its configuration alone: the
    file keeps the plan's floor, margin 0. A distance to a *moving* boom depends on timing; each
    boom's rows stay within ``tolerance`` of its plan at every point, so it needs ``2 tolerance``
    (the oracle's floor, :mod:`pipeline.round.oracle`)."""
    return {"self": float(self_m), "tunnel": float(tunnel_m), "boom": 2 * tolerance if others_move else 0.0}


def kind_of(key: str) -> str:
    """The kind of a clearance key: ``self``, ``tunnel`` (wall, ground, arch, tunnel) or ``boom``."""
    return "self" if key == "self" else "boom" if key.startswith("boom") else "tunnel"


def lever_arms(boom: Boom) -> torch.Tensor:
    """Per joint, an upper bound (m) of the distance of any capsule point moved by that joint from a
    point of the joint's axis, over every configuration within the joint ranges; 1 for prismatic
    joints (a unit step moves every point it moves by 1). Float64 ``(n_joints,)``.

    From the axis frame ``F`` of joint i to a capsule end fixed ``along_z`` on frame ``f``: rows
    ``F .. f-1`` each move the origin by at most ``|a| + |d|`` (largest over their joint's range).
    In the modified convention the last row's ``d`` and the end's ``along_z`` are both along the
    frame's z, so they count together as ``|d + along_z|`` (jumbo8's feed start ``H - 4.5 z8`` is
    at most 3.5 m from frame 7 along z, not 3.5 + 4.5). The tool frame adds ``|tool|``. Capsule
    points are convex combinations of their ends, so the ends' bound covers them."""
    modified = boom.convention == "modified"
    span = {}  # (row, param) -> (lowest, highest) value over its joint's range
    for j in boom.joints:
        lo, hi = (j.locked, j.locked) if j.locked is not None else (j.lower, j.upper)
        span[(j.row, j.param)] = (lo, hi)

    def extent(row: int, param: str, add: float = 0.0) -> float:
        base = boom.rows[row][1 if param == "a" else 3]
        lo, hi = span.get((row, param), (0.0, 0.0))
        return max(abs(base + lo + add), abs(base + hi + add))

    ends = [p for b in boom.bodies.values() for p in (b.start, b.end)]
    tool = math.hypot(*boom.tool)
    out = []
    for j in boom.joints:
        if not j.revolute:
            out.append(1.0)
            continue
        axis_frame = j.row if (j.param == "a") == modified else j.row + 1
        best = 0.0
        for e in ends:
            f = min(e.frame, boom.n_rows)  # the tool frame is frame n_rows moved by `tool`
            if e.frame < j.row + 1:  # not moved by this joint
                continue
            reach = sum(extent(m, "a") + extent(m, "d") for m in range(axis_frame, f))
            if modified and f > axis_frame and e.along_z:  # last row's d and along_z share one z axis
                reach += extent(f - 1, "d", e.along_z) - extent(f - 1, "d")
            else:
                reach += abs(e.along_z)
            if e.frame == boom.tool_index:
                reach += tool
            best = max(best, reach)
        out.append(best)
    return torch.tensor(out, dtype=torch.float64)


Other = torch.Tensor | Timed  # a standing configuration (n,) or a timed path (rig clock)


@dataclass(frozen=True)
class Clearance:
    """The smallest clearances (m, negative: broken) over the checked instants of a motion."""

    self: float
    tunnel: float
    boom: float  # inf when the rig has no other boom
    instants: int  # how many instants were checked
    first_violation: float | None = None  # seconds from the motion's start, None when clear
    broken: str = ""  # what broke first: "self", "wall", "ground", "arch" or "boom <name>"
    floor: float = -math.inf  # certified lower bound of every clearance at every instant (module doc)
    floors: dict[str, float] | None = None  # the floor per kind (KINDS); None when no drift was given

    @property
    def clear(self) -> bool:
        return self.first_violation is None

    def short(self, margin: Mapping[str, float]) -> dict[str, float]:
        """The kinds whose certified floor is below ``margin[kind]``, with their floor (all when unknown)."""
        floors = self.floors or {k: -math.inf for k in KINDS}
        return {k: f for k, f in floors.items() if f < margin[k]}

    def certified(self, margin: Mapping[str, float]) -> bool:
        """Clear at every instant by at least ``margin`` of each kind (not only at the checked ones)."""
        return self.clear and not self.short(margin)

    def sampled_at_least(self, margin: Mapping[str, float]) -> bool:
        """Every sampled clearance >= its kind's margin: a finer sampling may certify the motion."""
        return self.self >= margin["self"] and self.tunnel >= margin["tunnel"] and self.boom >= margin["boom"]

    def as_dict(self) -> dict[str, float]:
        return {"self": self.self, "tunnel": self.tunnel, "boom": self.boom}


def others_of(rig: Rig, index: int, others: Mapping | None) -> dict[int, Timed]:
    """Every other boom of the rig as a :class:`Timed` path: those in ``others`` (by name or index;
    a standing configuration or a timed path), the rest standing at their park."""
    given = {}
    for key, value in (others or {}).items():
        j = rig.index(key) if isinstance(key, str) else int(key)
        if j == index or not 0 <= j < len(rig):
            raise InputError(f"others: boom {key!r} is not another boom of rig '{rig.name}' {rig.names} "
                             f"(the moving boom is '{rig.names[index]}')")
        given[j] = value if isinstance(value, Timed) else Timed.standing(value.to(torch.float64))
    return {j: given.get(j, Timed.standing(rig.booms[j].park)) for j in range(len(rig)) if j != index}


def clearances_at(rig: Rig, index: int, q: torch.Tensor, others: Mapping[int, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Per instant ``(K,)``: self, wall, ground, arch of boom ``index`` at ``q (K, n)``, and its
    boom-boom clearance ``"boom <name>"`` to each other boom ``j`` at ``others[j] (K, n)`` (or
    ``(1, n)``, standing). One batch per boom and kind (the compiled kernels where they apply:
    :meth:`MountedBoom.clearances`, :meth:`Rig.boom_clearance`)."""
    out = dict(rig.booms[index].clearances(q))
    for j, qj in others.items():
        out[f"boom {rig.names[j]}"] = rig.boom_clearance(index, q, j, qj).expand(q.shape[0])
    return out


def summarise(values: dict[str, torch.Tensor], t: torch.Tensor, drift: dict[str, torch.Tensor] | None = None
              ) -> Clearance:
    """The smallest of each clearance over the instants ``t (K,)``, the first instant where any is
    below 0, and, given each clearance's drift bound over each interval ``(K - 1,)``, the floor."""
    tunnel = torch.stack([values[k] for k in SURFACES]).amin(0)
    boom_keys = [k for k in values if k.startswith("boom ")]
    boom = torch.stack([values[k] for k in boom_keys]).amin(0) if boom_keys else None
    keys = list(values)
    worst = torch.stack([values[k] for k in keys])  # (kinds, K)
    bad = (worst < 0).any(0)
    first, broken = None, ""
    if bool(bad.any()):
        k = int(torch.nonzero(bad)[0, 0])
        first, broken = float(t[k]), keys[int(torch.argmin(worst[:, k]))]
    floor, floors = -math.inf, None
    if drift is not None:
        if t.shape[0] > 1:
            lo = torch.minimum(worst[:, 1:], worst[:, :-1])
            mid = 0.5 * (worst[:, 1:] + worst[:, :-1] - torch.stack([drift[k] for k in keys]))
            per_key = torch.minimum(lo, mid).amin(1)
        else:
            per_key = worst.amin(1)
        floor = float(per_key.min())
        floors = {k: math.inf for k in KINDS}
        for key, f in zip(keys, per_key.tolist(), strict=True):
            floors[kind_of(key)] = min(floors[kind_of(key)], f)
    return Clearance(float(values["self"].min()), float(tunnel.min()),
                     float(boom.min()) if boom is not None else math.inf, int(t.shape[0]), first, broken, floor,
                     floors)


def _drift(rig: Rig, index: int, q: torch.Tensor, at: Mapping[int, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Each clearance's drift bound over each interval ``(K - 1,)`` of instants (module doc)."""
    own = travel(q[1:] - q[:-1], lever_arms(rig.booms[index].boom))
    drift = {"self": 2 * own, **{k: own for k in SURFACES}}
    for j, qj in at.items():
        drift[f"boom {rig.names[j]}"] = own + travel(qj[1:] - qj[:-1], lever_arms(rig.booms[j].boom))
    return drift


def check(rig: Rig, index: int, t: torch.Tensor, q: torch.Tensor, others: Mapping | None = None,
          t0: float = 0.0) -> Clearance:
    """Clearances of boom ``index`` at joints ``q (K, n)`` at times ``t (K,)`` (seconds from the
    motion's start, which is ``t0`` on the others' clock), every other boom where it is then."""
    if q.ndim != 2 or t.shape != q.shape[:1]:
        raise InputError(f"check: expected t (K,) and q (K, n), got {tuple(t.shape)} and {tuple(q.shape)}")
    at = {j: o.at(t + t0) for j, o in others_of(rig, index, others).items()}
    return summarise(clearances_at(rig, index, q, at), t, _drift(rig, index, q, at))


def _instants(rig: Rig, index: int, path: Path, timed: Mapping[int, Timed], t0: float, resolution: float):
    t = path.check_instants(lever_arms(rig.booms[index].boom), resolution)
    for j, o in timed.items():
        if o.t.shape[0] > 1:  # moving: add its own instants within the window
            t = torch.cat([t, o.instants(lever_arms(rig.booms[j].boom), resolution, t0, t0 + path.duration) - t0])
    return distinct(t)


def check_path(rig: Rig, index: int, path: Path, others: Mapping | None = None, t0: float = 0.0,
               resolution: float = RESOLUTION) -> Clearance:
    """:func:`check` of a planned path at instants where no point of this boom, nor of any moving
    other boom, moves more than ``resolution`` between two checks (the module's bound)."""
    t = _instants(rig, index, path, others_of(rig, index, others), t0, resolution)
    return check(rig, index, t, path.positions(t), others, t0)


def certify_path(rig: Rig, index: int, path: Path, margin: Mapping[str, float], others: Mapping | None = None,
                 t0: float = 0.0, resolution: float = RESOLUTION, refinements: int = REFINEMENTS) -> Clearance:
    """:func:`check_path`, refined while the motion is clear at every sample by its margins but a
    certified floor is still short of them: each interval whose floor is short is halved (the
    instant halfway along its line added: :meth:`Path.halfway`; the floor's gap below the samples
    shrinks with the interval's travel), up to
    ``refinements`` times. Every interval lies on one straight segment of this boom and one row
    interval of each moving other (the instants hold every segment's and row's ends), so a half's
    drift bound is its own chord's travel. The last check is returned: :meth:`Clearance.certified`
    says whether it proves ``margin`` at every instant."""
    timed = others_of(rig, index, others)
    t = _instants(rig, index, path, timed, t0, resolution)
    q = path.positions(t)
    at = {j: o.at(t + t0) for j, o in timed.items()}
    values = clearances_at(rig, index, q, at)
    for level in range(refinements + 1):
        drift = _drift(rig, index, q, at)
        c = summarise(values, t, drift)
        if level == refinements or c.certified(margin) or not (c.clear and c.sampled_at_least(margin)):
            return c
        short = torch.zeros(t.shape[0] - 1, dtype=torch.bool)
        for key, x in values.items():  # samples keep their margins here: only the floor between can be short
            short |= 0.5 * (x[1:] + x[:-1] - drift[key]) < margin[kind_of(key)]
        mid = path.halfway(t[:-1][short], t[1:][short])
        q_mid = path.positions(mid)
        at_mid = {j: o.at(mid + t0) for j, o in timed.items()}
        v_mid = clearances_at(rig, index, q_mid, at_mid)
        order = torch.argsort(torch.cat([t, mid]))
        t, q = torch.cat([t, mid])[order], torch.cat([q, q_mid])[order]
        at = {j: torch.cat([at[j], at_mid[j]])[order] for j in at}
        values = {k: torch.cat([values[k], v_mid[k]])[order] for k in values}
    return c


@dataclass(frozen=True)
class StraightChecks:
    """Per straight move ``(M,)``: the smallest sampled clearance of each kind (``self``, ``tunnel``,
    ``boom <name>`` per other boom) and the certified floor of each (module doc: a lower bound at
    every instant of the move, not only the sampled ones)."""

    least: dict[str, torch.Tensor]
    floor: dict[str, torch.Tensor]

    def clear(self, kinds: tuple[str, ...] | None = None, margin: float | Mapping[str, float] = 0.0) -> torch.Tensor:
        """Moves whose sampled clearances of ``kinds`` (default all) are all >= ``margin`` (one value, or
        one per kind of :data:`KINDS`)."""
        keys = kinds or tuple(self.least)
        return torch.stack([self.least[k] >= _margin(margin, k) for k in keys]).all(0)

    def certified(self, kinds: tuple[str, ...] | None = None,
                  margin: float | Mapping[str, float] = 0.0) -> torch.Tensor:
        """Moves whose floors of ``kinds`` are all >= ``margin`` (clear at every instant)."""
        keys = kinds or tuple(self.floor)
        return torch.stack([self.floor[k] >= _margin(margin, k) for k in keys]).all(0)


def _margin(margin: float | Mapping[str, float], key: str) -> float:
    return float(margin) if isinstance(margin, (int, float)) else margin[kind_of(key)]


def certify_straight_moves(rig: Rig, index: int, qa: torch.Tensor, qb: torch.Tensor,
                           margin: Mapping[str, float], kinds: tuple[str, ...] = ("self", "tunnel"),
                           others: Mapping | None = None, resolution: float = RESOLUTION,
                           refinements: int = REFINEMENTS) -> StraightChecks:
    """:func:`check_straight_moves`, then, for the moves whose samples of ``kinds`` all keep
    ``margin`` but whose floor is short of it, each short interval halved (its midpoint in s added),
    up to ``refinements`` times: all those moves in one batch per halving, only the short intervals
    (a half's drift bound is its own share of the move's travel bound)."""
    checks = check_straight_moves(rig, index, qa, qb, others, resolution)
    least = {k: v.clone() for k, v in checks.least.items()}
    floor = {k: v.clone() for k, v in checks.floor.items()}
    out = StraightChecks(least, floor)
    todo = torch.nonzero(out.clear(kinds, margin) & ~out.certified(kinds, margin)).flatten()
    if not len(todo) or refinements < 1:
        return out
    me = rig.booms[index]
    standing = {f"boom {rig.names[j]}": (j, o.q[:1]) for j, o in others_of(rig, index, others).items()}
    a, step = qa[todo].to(torch.float64), (qb[todo] - qa[todo]).to(torch.float64)
    R = travel(step, lever_arms(me.boom))
    n = torch.ceil(R / resolution).clamp_min(1).long()
    which = torch.repeat_interleave(torch.arange(len(todo)), n + 1)
    first = torch.cumsum(n + 1, 0) - (n + 1)
    s = (torch.arange(which.shape[0]) - first[which]).to(torch.float64) / n[which].to(torch.float64)

    def values(w: torch.Tensor, x: torch.Tensor) -> dict[str, torch.Tensor]:
        with torch.inference_mode():
            q = a[w] + x[:, None] * step[w]
            c = me.clearances(q)
            out = {"self": c["self"], "tunnel": torch.stack([c[k] for k in SURFACES]).amin(0)}
            for key, (j, qj) in standing.items():
                if key in kinds:
                    out[key] = rig.boom_clearance(index, q, j, qj)
        return {k: v for k, v in out.items() if k in kinds}

    vals = values(which, s)
    drift = {k: 2.0 if k == "self" else 1.0 for k in kinds}
    for _ in range(refinements + 1):
        same = which[1:] == which[:-1]
        width = R[which[1:]] * (s[1:] - s[:-1])
        mids = {k: 0.5 * (x[1:] + x[:-1] - drift[k] * width) for k, x in vals.items()}
        short = torch.zeros_like(same)
        for k, m in mids.items():
            short |= same & (m < _margin(margin, k))
        if not bool(short.any()) or _ == refinements:
            break
        w_new, s_new = which[1:][short], 0.5 * (s[1:] + s[:-1])[short]
        v_new = values(w_new, s_new)
        order = torch.argsort(torch.cat([which, w_new]).to(torch.float64) * 2 + torch.cat([s, s_new]))
        which, s = torch.cat([which, w_new])[order], torch.cat([s, s_new])[order]
        vals = {k: torch.cat([vals[k], v_new[k]])[order] for k in vals}
    P = len(todo)
    for k, x in vals.items():
        lo = torch.full((P,), math.inf, dtype=torch.float64).scatter_reduce(0, which, x, "amin")
        m = torch.where(same, torch.minimum(mids[k], torch.minimum(x[1:], x[:-1])), torch.full_like(mids[k], math.inf))
        f = torch.full((P,), math.inf, dtype=torch.float64).scatter_reduce(0, which[1:], m, "amin")
        least[k][todo], floor[k][todo] = lo, torch.minimum(f, lo)
    return out


def check_straight_moves(rig: Rig, index: int, qa: torch.Tensor, qb: torch.Tensor, others: Mapping | None = None,
                         resolution: float = RESOLUTION, boom_only: bool = False, chunk: int = 200_000
                         ) -> StraightChecks:
    """:func:`check_path` of many straight moves of boom ``index`` at once, ``qa (M, n)`` to ``qb (M, n)``
    (``qb`` already unwrapped: the motion is ``qa + s (qb - qa)``), every other boom standing (its
    configuration in ``others``, else its park). Each move is sampled at ``ceil(R / resolution)``
    equal steps of s, ``R`` its travel bound, as :meth:`Path.check_instants` samples a segment (the
    timing along the line does not change which configurations it passes). With ``boom_only`` only
    the boom-boom clearances are computed (the screen of moves against booms at park).

    One batch of at most ``chunk`` configurations at a time: the kinematics and every clearance of a
    chunk in one call, the per-move minima by a scatter (no loop over moves)."""
    me = rig.booms[index]
    standing = {j: o.q[:1] for j, o in others_of(rig, index, others).items()}
    qa, qb = qa.to(torch.float64), qb.to(torch.float64)
    step = qb - qa
    M = qa.shape[0]
    R = travel(step, lever_arms(me.boom))
    n = torch.ceil(R / resolution).clamp_min(1).long()
    kinds = ([] if boom_only else ["self", "tunnel"]) + [f"boom {rig.names[j]}" for j in standing]
    drift = {"self": 2.0, "tunnel": 1.0, **{f"boom {rig.names[j]}": 1.0 for j in standing}}  # x R / n
    inf = lambda: torch.full((M,), math.inf, dtype=torch.float64)  # noqa: E731
    least, floor = {k: inf() for k in kinds}, {k: inf() for k in kinds}
    counts = n + 1
    ends = torch.cumsum(counts, 0)
    lo = 0
    while lo < M:  # moves grouped into chunks of about `chunk` configurations
        hi = int(torch.searchsorted(ends, ends[lo - 1] + chunk if lo else torch.tensor(chunk), right=True))
        hi = max(hi, lo + 1)
        which = torch.repeat_interleave(torch.arange(lo, hi), counts[lo:hi])
        first = (ends[lo:hi] - counts[lo:hi]) - (ends[lo - 1] if lo else 0)
        k = torch.arange(which.shape[0]) - first[which - lo]
        s = k.to(torch.float64) / n[which].to(torch.float64)
        q = qa[which] + s[:, None] * step[which]
        with torch.inference_mode():
            values = {}
            if not boom_only:
                c = me.clearances(q)
                values["self"] = c["self"]
                values["tunnel"] = torch.stack([c[k] for k in SURFACES]).amin(0)
            for j, qj in standing.items():
                values[f"boom {rig.names[j]}"] = rig.boom_clearance(index, q, j, qj)
        same = which[1:] == which[:-1]  # consecutive samples of one move: an interval
        for key, x in values.items():
            least[key][lo:hi] = torch.full((hi - lo,), math.inf, dtype=torch.float64).scatter_reduce(
                0, which - lo, x, "amin")
            mid = 0.5 * (x[1:] + x[:-1] - drift[key] * (R / n)[which[1:]])
            mid = torch.where(same, torch.minimum(mid, torch.minimum(x[1:], x[:-1])), torch.full_like(mid, math.inf))
            part = torch.full((hi - lo,), math.inf, dtype=torch.float64).scatter_reduce(0, which[1:] - lo, mid, "amin")
            floor[key][lo:hi] = torch.minimum(part, least[key][lo:hi])
        lo = hi
    return StraightChecks(least, floor)
