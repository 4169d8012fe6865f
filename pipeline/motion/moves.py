"""Collision-free moves of one boom of a rig, from configuration A to B (docs/reference.md, section 7).

:func:`plan_move` tries, in order, and returns the first motion certified clear at every instant
(:func:`pipeline.motion.checks.certify_path`: self, tunnel from the boom's base, d_boom to every other
boom standing or moving, no point moving more than 1 cm between checks, and each kind's certified
floor between checks at least its margin, the checks refined where it is short):

1. ``straight``: the synchronised straight line in joint space (:func:`pipeline.motion.timing.profile`);
   its duration is exactly the move time.
2. ``retract``: feed back along the feed joint (the boom's last prismatic joint, jumbo8's q8) to its
   lower limit, travel in a straight line of the other joints, feed forward; three rest-to-rest
   segments.
3. ``planned``: a sampling planner, OMPL's RRTConnect (Python bindings, ``pip install ompl``), in
   joint space within the joint ranges (with ``box_margin``, first within the box spanned by A and B
   widened by that share of each range: a detour near the straight line, which keeps out of the
   space of booms working beside it; then the whole ranges), then OMPL's path simplifier (vertex reduction and
   shortcutting), then the reference's profile on each edge, stopping at each waypoint, and the dense check
   again. OMPL because it is the maintained reference library of sampling planners (BSD, Kavraki
   Lab at Rice; MoveIt's default planners), ships Python wheels (2.0: cp311, no build), and has a
   bidirectional RRT and a shortcutting simplifier ready; its state and edge checks call back into
   this project's clearances, so the planner and the checks cannot disagree on what is clear.

A move that no attempt made clear is returned as ``failed`` with the reason (each attempt's first
violation), never as clear: its rows are the straight line's, for inspection, not for execution.

Planner details. States are joints scaled by the joint speeds (``q_i / v_i``, seconds at top speed),
so the planner's distance, and the simplifier's path length, approximate move time. Full-turn joints
(q4, q7) are unwrapped: the goal is A plus the short-way step, and those joints may range a half turn
beyond A and B. A state is valid when every clearance is >= its margin; an edge is valid when it is
certified so at the 1 cm resolution of the checks, refined where the floor is short (the same
instants the final check uses). The search and the simplifier stop after counts of iterations, OMPL's
RNG seeded before each search (reproducible); wall-time budgets are opt-in (``PlannerSettings``).
Other booms standing are
obstacles where they stand. Other booms moving are planned against their *sweep*: every
configuration their timed path takes from the move's start on (they stand at their last row after
it), sampled every ``sweep_step`` metres of point travel and kept ``sweep_step / 2`` further away,
which covers every configuration between two samples. That is conservative (the boom avoids where
the other boom will be at any time, not just when), and it needs no guess of the planned move's
timing; the final check then uses the real instants. When the sweep leaves no way, the move fails
with that reason rather than waiting; waiting is the round planner's decision.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from pipeline.core.errors import InputError
from pipeline.geometry.rig import Rig
from pipeline.motion.checks import (
    REFINEMENTS,
    RESOLUTION,
    Clearance,
    certify_path,
    clearances_at,
    kind_of,
    lever_arms,
    margins,
    others_of,
)
from pipeline.motion.path import Path, Timed, travel, unwrapped
from pipeline.motion.timing import JointLimits, wrap

KINDS = ("straight", "retract", "planned")
TOLERANCE = 0.001  # m: the trajectory rows' linear interpolation stays this close to the motion


@dataclass(frozen=True)
class PlannerSettings:
    """The sampling planner's budget and its treatment of moving booms.

    By default the budget is a count (reproducible: the same seed and counts give the same path on
    any machine); ``time_s`` / ``simplify_s`` replace the counts by wall time (opt-in, interactive
    use: how far the search gets then depends on the machine's load, so results do not reproduce)."""

    iterations: int = 5000  # RRTConnect's iterations per search (its termination condition's evaluations)
    simplify_steps: int = 40  # the simplifier's termination condition's evaluations
    time_s: float | None = None  # wall-time budget of the search instead of ``iterations`` (not reproducible)
    simplify_s: float | None = None  # wall-time budget of the simplifier instead of ``simplify_steps``
    seed: int | None = 0  # before each plan, OMPL's global seed := seed + 1 (it ignores 0 once used); None: leave it
    sweep_step: float = 0.10  # m of point travel between samples of a moving boom's sweep
    box_margin: float | None = None  # first search near the straight line (module doc); None: whole ranges only
    refinements: int = REFINEMENTS  # halvings of the check's resolution where a floor is short (checks.py)

    def __post_init__(self):
        if self.seed is not None and int(self.seed) < 0:
            raise InputError(f"planner seed = {self.seed}: expected >= 0")
        if self.iterations < 1 or self.simplify_steps < 0:
            raise InputError(f"planner: iterations = {self.iterations} (>= 1), simplify_steps = "
                             f"{self.simplify_steps} (>= 0)")


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


def _why(kind: str, c: Clearance, margin: Mapping[str, float]) -> str:
    if c.clear:  # clear at every sample, but not certified at every instant
        short = ", ".join(f"{k} {f:.4f} m < {margin[k]:g} m" for k, f in c.short(margin).items())
        return f"{kind}: clear at the samples, certified floor short ({short})"
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
              kinds: Sequence[str] = KINDS, resolution: float = RESOLUTION, tolerance: float = TOLERANCE,
              margin: Mapping[str, float] | None = None) -> Move:
    """Move boom ``boom`` (name or index) of ``rig`` from ``qa`` to ``qb`` (SI joints, own base frame)
    starting at ``t0`` on the others' clock. ``others``: boom name or index -> a standing
    configuration ``(n,)`` or a :class:`Timed` path; booms not given stand at their park. ``kinds``
    restricts the attempts (in their fixed order). The end is ``qb`` up to full turns of q4, q7.

    An attempt is taken only when its certified floor of each kind (self, tunnel, boom) is at least
    ``margin`` of that kind (default :func:`pipeline.motion.checks.margins` for rows within
    ``tolerance``: the trajectory rows then stay clear too), the check refined where samples are
    clear but a floor is short (:func:`pipeline.motion.checks.certify_path`)."""
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
    if margin is None:
        margin = margins(tolerance, any(o.t.shape[0] > 1 for o in timed.values()))

    def certify(path: Path) -> Clearance:
        return certify_path(rig, index, path, margin, timed, t0, resolution, planner.refinements)

    def result(kind: str, path: Path, c: Clearance, reason: str) -> Move:
        t, q = path.rows(lever, tolerance)
        return Move(rig.names[index], kind, path.duration, t, q, c, path, reason, time.perf_counter() - started)

    straight = Path.through(torch.stack([qa, qb]), limits)
    c_straight = certify(straight)
    if "straight" in kinds and c_straight.certified(margin):
        return result("straight", straight, c_straight, "")
    notes = [_why("straight", c_straight, margin)] if not c_straight.certified(margin) else ["straight: not tried"]

    # The ends themselves against what stands still: if one is not clear, no motion can be.
    standing = {j: o.q for j, o in timed.items() if o.t.shape[0] == 1}
    ends = clearances_at(rig, index, torch.stack([qa, qb]), standing)
    low = {k: v for k, v in ends.items() if bool((v < margin[kind_of(k)]).any())}
    if low:
        key = next(iter(low))
        where = "start qa" if float(low[key][0]) < margin[kind_of(key)] else "end qb"
        notes.append(f"refused: the {where} itself has {key} clearance {float(low[key].min()):.4f} m, below its "
                     f"margin {margin[kind_of(key)]:g} m (standing obstacles and the boom itself)")
        return result("failed", straight, c_straight, "; ".join(notes))

    feed = _feed_joint(rig, index)
    if "retract" in kinds and feed is not None:
        lo = rig.booms[index].boom.limits(torch.float64)[0][feed]
        qa_in, qb_in = qa.clone(), qb.clone()
        qa_in[feed], qb_in[feed] = lo, lo
        path = Path.through(torch.stack([qa, qa_in, qb_in, qb]), limits)
        c = certify(path)
        if c.certified(margin):
            return result("retract", path, c, "; ".join(notes))
        notes.append(_why("retract", c, margin))

    if "planned" in kinds:
        waypoints, why = None, ""
        if planner.box_margin is not None:  # near the straight line first: a compact detour
            waypoints, why = _sample(rig, index, qa, qb, limits, timed, t0, lever, planner, resolution, margin,
                                     planner.box_margin)
            if waypoints is None:
                notes.append(f"planned (box margin {planner.box_margin:g}): {why}")
        if waypoints is None:
            waypoints, why = _sample(rig, index, qa, qb, limits, timed, t0, lever, planner, resolution, margin)
        if waypoints is None:
            notes.append(f"planned: {why}")
        else:
            path = Path.through(waypoints, limits)
            c = certify(path)
            if c.certified(margin):
                return result("planned", path, c, "; ".join(notes))
            notes.append(_why("planned", c, margin) + " (timed re-check)")
    return result("failed", straight, c_straight, "; ".join(notes))


class _Validity:
    """Batched validity of configurations ``(K, n)`` for the planner: every clearance >= its kind's
    margin against standing booms, and boom-boom >= ``sweep_step / 2`` plus the boom margin against
    every sample of each moving boom's sweep."""

    def __init__(self, rig: Rig, index: int, timed: Mapping[int, Timed], t0: float, sweep_step: float,
                 margin: Mapping[str, float]):
        self.rig, self.index, self.margin = rig, index, dict(margin)
        self.sweep_margin = sweep_step / 2 + margin["boom"]
        self.standing = {j: o.q for j, o in timed.items() if o.t.shape[0] == 1}
        self.sweeps = {j: o.sweep(lever_arms(rig.booms[j].boom), sweep_step, t0)
                       for j, o in timed.items() if o.t.shape[0] > 1}

    def slack(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each clearance less its margin ``(K, C)`` and, per column ``(C,)``, how many times this
        boom's point travel it can drift by between two samples (2 for self, else 1: module
        pipeline.motion.checks)."""
        values = clearances_at(self.rig, self.index, q, self.standing)
        cols = [v - self.margin[kind_of(k)] for k, v in values.items()]
        drift = [2.0 if k == "self" else 1.0 for k in values]
        for j, sweep in self.sweeps.items():  # (K, 1, n) against every sample of the sweep (1, M, n)
            cols.append(self.rig.boom_clearance(self.index, q[:, None], j, sweep[None]).amin(-1) - self.sweep_margin)
            drift.append(1.0)
        return torch.stack(cols, -1), torch.tensor(drift, dtype=torch.float64)

    def __call__(self, q: torch.Tensor) -> torch.Tensor:
        return self.slack(q)[0].ge(0).all(-1)

    def edge(self, q1: torch.Tensor, q2: torch.Tensor, lever: torch.Tensor, resolution: float,
             refinements: int) -> bool:
        """Whether the straight edge q1 -> q2 is certified clear by the margins at every point of it:
        samples at ``resolution`` of point travel, each interval whose floor is short (the samples
        clear) halved, up to ``refinements`` times (pipeline.motion.checks' bound)."""
        R = float(travel(q2 - q1, lever))
        k = max(1, math.ceil(R / resolution))
        s = torch.linspace(0, 1, k + 1, dtype=torch.float64)
        q = q1 + s[:, None] * (q2 - q1)
        if k >= 8 and not bool(self(q[::8]).all()):  # a coarse pass first: most bad edges fail it, at
            return False  # an eighth of the cost
        sl, drift = self.slack(q)
        for level in range(refinements + 1):
            if bool((sl < 0).any()):
                return False
            floor = 0.5 * (sl[1:] + sl[:-1] - drift * (R * (s[1:] - s[:-1]))[:, None])  # less the margin
            short = (floor < 0).any(-1)
            if not bool(short.any()):
                return True
            if level == refinements:
                return False
            mid = 0.5 * (s[1:] + s[:-1])[short]
            order = torch.argsort(torch.cat([s, mid]))
            s = torch.cat([s, mid])[order]
            sl = torch.cat([sl, self.slack(q1 + mid[:, None] * (q2 - q1))[0]])[order]
        return False


def _budget(ob, count: int, seconds: float | None):
    """OMPL's termination condition: after ``count`` evaluations of it (one per planner iteration, or
    per simplifier round: the same on every machine), or, given ``seconds``, after that wall time."""
    if seconds is not None:
        return ob.timedPlannerTerminationCondition(float(seconds))
    calls = itertools.count()
    return ob.PlannerTerminationCondition(lambda: next(calls) >= count)


def _sample(rig, index, qa, qb, limits, timed, t0, lever, settings: PlannerSettings, resolution,
            margin: Mapping[str, float], box_margin: float | None = None):
    """RRTConnect from ``qa`` to ``qb`` (unwrapped), simplified: waypoints ``(W, n)`` or ``(None, why)``.
    ``box_margin``: search only the box spanned by qa and qb widened by that share of each joint's
    range (a detour that stays near the straight line, out of the way of other booms). Every edge
    OMPL keeps is certified clear by ``margin`` (:meth:`_Validity.edge`)."""
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    valid = _Validity(rig, index, timed, t0, settings.sweep_step, margin)
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
        """An edge is valid when certified clear by the margins (:meth:`_Validity.edge`)."""

        def checkMotion(self, s1, s2):  # noqa: N802  OMPL's name
            return valid.edge(joints(s1), joints(s2), lever, resolution, settings.refinements)

    edge = Edge(si)
    si.setMotionValidator(edge)
    si.setup()
    if settings.seed is not None:  # OMPL complains when reseeded after first use; the reseed works for the
        level = ou.getLogLevel()  # samplers made after it (this search's), but a seed of 0 is then ignored
        ou.setLogLevel(ou.LOG_NONE)
        ou.RNG.setSeed(int(settings.seed) + 1)
        ou.setLogLevel(level)
    ou.setLogLevel(ou.LOG_WARN)
    start, goal = space.allocState(), space.allocState()
    for i in range(n):
        start[i], goal[i] = float(qa[i] / v[i]), float(qb[i] / v[i])
    ss = og.SimpleSetup(si)
    ss.setStartAndGoalStates(start, goal)
    ss.setPlanner(og.RRTConnect(si))
    search = _budget(ob, settings.iterations, settings.time_s)
    solved = ss.solve(search)
    if not ss.haveExactSolutionPath():
        budget = f"{settings.time_s:g} s" if settings.time_s is not None else f"{settings.iterations} iterations"
        return None, f"RRTConnect found no clear path in {budget} ({solved})"
    path = ss.getSolutionPath()
    simplifier = og.PathSimplifier(si)
    if settings.simplify_steps or settings.simplify_s is not None:
        simplifier.simplify(path, _budget(ob, settings.simplify_steps, settings.simplify_s))
    simplifier.reduceVertices(path)
    w = torch.stack([joints(s) for s in path.getStates()])
    w[0], w[-1] = qa, qb  # exactly the requested ends (OMPL copies them; the goal threshold is ~eps)
    return w, ""
