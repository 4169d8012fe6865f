"""Collision-free moves of one boom of a rig, from configuration A to B (spec section 7, issue 19).

:func:`plan_move` tries, in order, and returns the first motion that checks clear at every instant
(:func:`pipeline.motion.checks.check_path`: self, tunnel from the boom's base, d_boom to every other
boom standing or moving, no point moving more than 1 cm between checks):

1. ``straight``: the synchronised straight line in joint space (:func:`pipeline.motion.timing.profile`);
   its duration is exactly the move time.
2. ``retract``: feed back along the feed joint (the boom's last prismatic joint, jumbo8's q8) to its
   lower limit, travel in a straight line of the other joints, feed forward; three rest-to-rest
   segments.
3. ``planned``: a sampling planner, OMPL's RRTConnect (Python bindings, ``pip install ompl``), in
   joint space within the joint ranges (with ``box_margin``, first within the box spanned by A and B
   widened by that share of each range: a detour near the straight line, which keeps out of the
   space of booms working beside it; then the whole ranges), then OMPL's path simplifier (vertex reduction and
   shortcutting), then the spec's profile on each edge, stopping at each waypoint, and the dense check
   again. OMPL because it is the maintained reference library of sampling planners (BSD, Kavraki
   Lab at Rice; MoveIt's default planners), ships Python wheels (2.0: cp311, no build), and has a
   bidirectional RRT and a shortcutting simplifier ready; its state and edge checks call back into
   this project's clearances, so the planner and the checks cannot disagree on what is clear.

A move that no attempt made clear is returned as ``failed`` with the reason (each attempt's first
violation), never as clear: its rows are the straight line's, for inspection, not for execution.

Planner details. States are joints scaled by the joint speeds (``q_i / v_i``, seconds at top speed),
so the planner's distance, and the simplifier's path length, approximate move time. Full-turn joints
(q4, q7) are unwrapped: the goal is A plus the short-way step, and those joints may range a half turn
beyond A and B. A state is valid when every clearance is >= 0; an edge is valid when it is at the
1 cm resolution of the checks (the same instants the final check uses). Other booms standing are
obstacles where they stand. Other booms moving are planned against their *sweep*: every
configuration their timed path takes from the move's start on (they stand at their last row after
it), sampled every ``sweep_step`` metres of point travel and kept ``sweep_step / 2`` further away,
which covers every configuration between two samples. That is conservative (the boom avoids where
the other boom will be at any time, not just when), and it needs no guess of the planned move's
timing; the final check then uses the real instants. When the sweep leaves no way, the move fails
with that reason rather than waiting; waiting is the round planner's decision.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from pipeline.core.errors import InputError
from pipeline.geometry.rig import Rig
from pipeline.motion.checks import (
    RESOLUTION,
    Clearance,
    check_path,
    clearances_at,
    lever_arms,
    others_of,
    summarise,
)
from pipeline.motion.path import Path, Timed, travel, unwrapped
from pipeline.motion.timing import JointLimits, wrap

KINDS = ("straight", "retract", "planned")
TOLERANCE = 0.001  # m: the trajectory rows' linear interpolation stays this close to the motion


@dataclass(frozen=True)
class PlannerSettings:
    """The sampling planner's budget and its treatment of moving booms."""

    time_s: float = 5.0  # RRTConnect's time budget per move
    simplify_s: float = 1.0  # the simplifier's time budget
    seed: int | None = 0  # OMPL's global seed, set before each plan (None: leave it)
    sweep_step: float = 0.10  # m of point travel between samples of a moving boom's sweep
    box_margin: float | None = None  # first search near the straight line (module doc); None: whole ranges only


@dataclass(frozen=True)
class Move:
    """A move of boom ``boom``: its motion (``path``), trajectory rows ``t (K,)`` s from its start and
    ``q (K, n)`` (unwrapped joints, linear in t between rows, within 1 mm of the motion at every boom
    point), duration (s) and smallest clearances over it."""

    boom: str
    kind: str  # straight, retract, planned or failed
    duration: float
    t: torch.Tensor
    q: torch.Tensor
    clearance: Clearance
    path: Path
    reason: str = ""  # why the earlier attempts (or, for failed, every attempt) were not clear
    planning_s: float = 0.0  # wall-clock seconds spent planning and checking

    @property
    def clear(self) -> bool:
        return self.kind != "failed"

    @property
    def clearances(self) -> dict[str, float]:
        """Smallest self, tunnel and boom-boom clearance (m) over the move."""
        return self.clearance.as_dict()

    def timed(self, t0: float = 0.0) -> Timed:
        """The rows on a rig clock where the move starts at ``t0``: how another boom's check sees it."""
        return Timed(self.t + t0, self.q)


def _why(kind: str, c: Clearance) -> str:
    value = {"self": c.self, "boom": c.boom}.get(c.broken.split()[0], c.tunnel)
    return f"{kind}: {c.broken} clearance {value:.3f} m at {c.first_violation:.2f} s"


def _feed_joint(rig: Rig, index: int) -> int | None:
    prismatic = [i for i, j in enumerate(rig.booms[index].boom.joints) if not j.revolute and j.locked is None]
    return prismatic[-1] if prismatic else None


def _check_input(rig: Rig, index: int, q: torch.Tensor, name: str, limits: JointLimits) -> torch.Tensor:
    boom = rig.booms[index].boom
    q = boom.check_joints(q, name).to(torch.float64)
    if q.ndim != 1:
        raise InputError(f"{name}: expected one configuration (n_joints,), got shape {tuple(q.shape)}")
    if not bool(boom.within_limits(wrap(q, limits))):
        raise InputError(f"{name} = {q.tolist()}: outside the joint ranges of boom '{rig.names[index]}' "
                         f"({boom.name})")
    return q


def plan_move(rig: Rig, boom: int | str, qa: torch.Tensor, qb: torch.Tensor, limits: JointLimits,
              others: Mapping | None = None, t0: float = 0.0, *, planner: PlannerSettings = PlannerSettings(),
              kinds: Sequence[str] = KINDS, resolution: float = RESOLUTION, tolerance: float = TOLERANCE) -> Move:
    """Move boom ``boom`` (name or index) of ``rig`` from ``qa`` to ``qb`` (SI joints, own base frame)
    starting at ``t0`` on the others' clock. ``others``: boom name or index -> a standing
    configuration ``(n,)`` or a :class:`Timed` path; booms not given stand at their park. ``kinds``
    restricts the attempts (in their fixed order). The end is ``qb`` up to full turns of q4, q7."""
    started = time.perf_counter()
    index = rig.index(boom) if isinstance(boom, str) else int(boom)
    if not 0 <= index < len(rig):
        raise InputError(f"boom = {boom!r}: rig '{rig.name}' has booms {rig.names}")
    unknown = sorted(set(kinds) - set(KINDS))
    if unknown:
        raise InputError(f"kinds: unknown {unknown}; expected some of {list(KINDS)}")
    qa = _check_input(rig, index, qa, "qa", limits)
    qb = unwrapped(qa, _check_input(rig, index, qb, "qb", limits), limits)
    timed = others_of(rig, index, others)
    lever = lever_arms(rig.booms[index].boom)

    def result(kind: str, path: Path, c: Clearance, reason: str) -> Move:
        t, q = path.rows(lever, tolerance)
        return Move(rig.names[index], kind, path.duration, t, q, c, path, reason, time.perf_counter() - started)

    straight = Path.through(torch.stack([qa, qb]), limits)
    c_straight = check_path(rig, index, straight, timed, t0, resolution)
    if "straight" in kinds and c_straight.clear:
        return result("straight", straight, c_straight, "")
    notes = [_why("straight", c_straight)] if not c_straight.clear else ["straight: not tried"]

    # The ends themselves against what stands still: if one is not clear, no motion can be.
    standing = {j: o.q for j, o in timed.items() if o.t.shape[0] == 1}
    ends = summarise(clearances_at(rig, index, torch.stack([qa, qb]), standing),
                     torch.tensor([0.0, 1.0], dtype=torch.float64))
    if not ends.clear:
        where = "start qa" if ends.first_violation == 0.0 else "end qb"
        notes.append(f"refused: the {where} itself breaks {ends.broken} (standing obstacles and the boom itself)")
        return result("failed", straight, c_straight, "; ".join(notes))

    feed = _feed_joint(rig, index)
    if "retract" in kinds and feed is not None:
        lo = rig.booms[index].boom.limits(torch.float64)[0][feed]
        qa_in, qb_in = qa.clone(), qb.clone()
        qa_in[feed], qb_in[feed] = lo, lo
        path = Path.through(torch.stack([qa, qa_in, qb_in, qb]), limits)
        c = check_path(rig, index, path, timed, t0, resolution)
        if c.clear:
            return result("retract", path, c, "; ".join(notes))
        notes.append(_why("retract", c))

    if "planned" in kinds:
        waypoints, why = None, ""
        if planner.box_margin is not None:  # near the straight line first: a compact detour
            waypoints, why = _sample(rig, index, qa, qb, limits, timed, t0, lever, planner, resolution,
                                     planner.box_margin)
            if waypoints is None:
                notes.append(f"planned (box margin {planner.box_margin:g}): {why}")
        if waypoints is None:
            waypoints, why = _sample(rig, index, qa, qb, limits, timed, t0, lever, planner, resolution)
        if waypoints is None:
            notes.append(f"planned: {why}")
        else:
            path = Path.through(waypoints, limits)
            c = check_path(rig, index, path, timed, t0, resolution)
            if c.clear:
                return result("planned", path, c, "; ".join(notes))
            notes.append(_why("planned", c) + " (timed re-check)")
    return result("failed", straight, c_straight, "; ".join(notes))


class _Validity:
    """Batched validity of configurations ``(K, n)`` for the planner: every clearance >= 0 against
    standing booms, and boom-boom >= ``margin`` against every sample of each moving boom's sweep."""

    def __init__(self, rig: Rig, index: int, timed: Mapping[int, Timed], t0: float, sweep_step: float):
        self.rig, self.index, self.margin = rig, index, sweep_step / 2
        self.standing = {j: o.q for j, o in timed.items() if o.t.shape[0] == 1}
        self.sweeps = {j: o.sweep(lever_arms(rig.booms[j].boom), sweep_step, t0)
                       for j, o in timed.items() if o.t.shape[0] > 1}
        self.frames = {j: rig.booms[j].frames(q) for j, q in self.sweeps.items()}

    def __call__(self, q: torch.Tensor) -> torch.Tensor:
        values = clearances_at(self.rig, self.index, q, self.standing)
        ok = torch.stack(list(values.values())).ge(0).all(0)
        if self.sweeps:
            mine = self.rig.booms[self.index].frames(q)[:, None]  # (K, 1, F, 4, 4) against (1, M, ...)
            for j, fj in self.frames.items():
                a, b = (mine, fj[None]) if self.index < j else (fj[None], mine)
                pair = self.rig.pair(min(self.index, j), max(self.index, j))
                ok &= pair.clearance(a, b).amin(-1) >= self.margin
        return ok


def _sample(rig, index, qa, qb, limits, timed, t0, lever, settings: PlannerSettings, resolution,
            box_margin: float | None = None):
    """RRTConnect from ``qa`` to ``qb`` (unwrapped), simplified: waypoints ``(W, n)`` or ``(None, why)``.
    ``box_margin``: search only the box spanned by qa and qb widened by that share of each joint's
    range (a detour that stays near the straight line, out of the way of other booms)."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    valid = _Validity(rig, index, timed, t0, settings.sweep_step)
    if not bool(valid(torch.stack([qa, qb])).all()):
        return None, "the start or the end lies in a moving boom's sweep (kept sweep_step / 2 away)"
    boom = rig.booms[index].boom
    v = torch.tensor(limits.v, dtype=torch.float64)
    lo, hi = boom.limits(torch.float64)
    turn = torch.tensor(limits.wrap)
    lo = torch.where(turn, torch.minimum(qa, qb) - math.pi, lo)
    hi = torch.where(turn, torch.maximum(qa, qb) + math.pi, hi)
    if box_margin is not None:
        widen = box_margin * (hi - lo)
        lo, hi = torch.maximum(lo, torch.minimum(qa, qb) - widen), torch.minimum(hi, torch.maximum(qa, qb) + widen)
    n = boom.n_joints
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):  # OMPL needs low < high: a locked joint gets a sliver, snapped back below
        bounds.setLow(i, float(lo[i] / v[i]))
        bounds.setHigh(i, float(max(hi[i], lo[i] + 1e-9) / v[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    locks = boom.with_locks

    def joints(state) -> torch.Tensor:
        return locks(torch.tensor([state[i] for i in range(n)], dtype=torch.float64) * v)

    si.setStateValidityChecker(lambda s: bool(valid(joints(s)[None])[0]))

    class Edge(ob.MotionValidator):
        """An edge is valid when clear at the checks' resolution (1 cm of point travel)."""

        def checkMotion(self, s1, s2):  # noqa: N802  OMPL's name
            q1, q2 = joints(s1), joints(s2)
            k = max(1, math.ceil(float(travel(q2 - q1, lever)) / resolution))
            a = torch.linspace(0, 1, k + 1, dtype=torch.float64)[:, None]
            q = q1 + a * (q2 - q1)
            coarse = torch.zeros(k + 1, dtype=torch.bool)
            coarse[::8] = True  # a coarse pass first: most invalid edges fail it, at an eighth of the cost
            return bool(valid(q[coarse]).all()) and (bool(coarse.all()) or bool(valid(q[~coarse]).all()))

    edge = Edge(si)
    si.setMotionValidator(edge)
    si.setup()
    if settings.seed is not None:  # OMPL complains when reseeded after first use; the reseed works
        level = ou.getLogLevel()
        ou.setLogLevel(ou.LOG_NONE)
        ou.RNG.setSeed(int(settings.seed))
        ou.setLogLevel(level)
    ou.setLogLevel(ou.LOG_WARN)
    start, goal = space.allocState(), space.allocState()
    for i in range(n):
        start[i], goal[i] = float(qa[i] / v[i]), float(qb[i] / v[i])
    ss = og.SimpleSetup(si)
    ss.setStartAndGoalStates(start, goal)
    ss.setPlanner(og.RRTConnect(si))
    solved = ss.solve(settings.time_s)
    if not ss.haveExactSolutionPath():
        return None, f"RRTConnect found no clear path in {settings.time_s:g} s ({solved})"
    path = ss.getSolutionPath()
    simplifier = og.PathSimplifier(si)
    simplifier.simplify(path, settings.simplify_s)
    simplifier.reduceVertices(path)
    w = torch.stack([joints(s) for s in path.getStates()])
    w[0], w[-1] = qa, qb  # exactly the requested ends (OMPL copies them; the goal threshold is ~eps)
    return w, ""
