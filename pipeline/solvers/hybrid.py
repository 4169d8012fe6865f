"""The product solver: a trained network's answer refined to the exact pose, with the safety model
as a constraint, and an honest status for every hole.

1. **Start** from the network (CUIKM by default): one forward pass lands within millimetres of a
   solution that is usually clear of the tunnel and of the boom itself.
2. **Refine** in float64 by damped least squares (Levenberg-Marquardt) on stacked rows: the 6-D
   pose residual ``pose6(q) - P``, and for each clearance below ``margin`` a row
   ``w (c_k(q) - margin)``. The rows use the analytic geometric Jacobian of the collar and the
   preview point and the analytic clearance gradients (:meth:`SafetyModel.clearances_with_jacobians`),
   all from one forward pass; autograd is only the tests' oracle. The 2 redundant joints of an
   8-joint boom let the clearance rows push the boom clear without giving up the pose.
3. **More starts** for the holes that are not yet exact and clear: perturbations of the network's
   answer, then seeded random joint vectors, all in one batch; each start is refined with the
   safety rows and without them (the latter answers "can the pose be reached at all?").
4. **One status per hole**, from every candidate found, in this order:

   * ``ok``: hole-seeking error <= ``tol_mm`` and every clearance >= 0 (the safety distances hold);
   * ``inexact``: clear, but the error is between ``tol_mm`` and ``reach_tol_mm``;
   * ``unsafe``: reached within ``reach_tol_mm`` (exact, or inexact), but every such solution found
     violates a safety distance;
   * ``unreachable``: no start reached the pose within ``reach_tol_mm``, whatever the collisions.

   Every hole keeps its best joints and their clearances; nothing is dropped.

**Other booms of a rig** (:class:`BoomObstacle`): a boom of a rig is solved in the rig frame (its
``base`` offset moves its frames there, so the tunnel is seen from its base and the target is in the rig
frame, while the joints stay in its own base frame). Booms standing where given are obstacles: each adds
one clearance, the boom-boom one (:class:`pipeline.geometry.boom_pair.BoomPair`: smallest capsule distance
less d_boom), with its row ``w (c - margin)`` active below ``margin`` like the others, its analytic
gradient with respect to the solved boom's joints, and its place in the ok rule (every clearance >= 0).
Without a base and obstacles the solver runs exactly as before (same operations, same numbers).

Joints whose range spans a full turn (jumbo8's boom rotation and roll-over) wrap around instead of
stopping at +-180 deg; the others are projected onto their limits.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import SEED_MAX, rule
from pipeline.geometry.boom_pair import BoomPair
from pipeline.geometry.collision import SAFETY_KINDS, SafetyModel
from pipeline.geometry.kinematics import pose_errors
from pipeline.geometry.rig import translate_frames
from pipeline.optim.least_squares import Damping, Evaluation, least_squares, projector
from pipeline.solvers.base import HoleTargets, JointSpace, Solver, SolveResult, Targets

STATUSES = ("ok", "inexact", "unsafe", "unreachable")
# Bounds (conf/solver/hybrid.yaml): LM converges in a handful of iterations or not at all, and every start of every
# hole not yet ok is refined in one batch (about 16 KB a start measured, jumbo8 with its safety terms)
MAX_ITERS = 1000
MAX_STARTS = 1024


@dataclass(frozen=True)
class HybridSettings:
    """The ``solver`` group (conf/solver/hybrid.yaml), read by solve and benchmark: tolerances, budget and starts."""

    tol_mm: float = field(default=0.01, metadata=rule(gt=0))  # exact: hole-seeking error at most this
    reach_tol_mm: float = field(default=1.0, metadata=rule(gt=0))  # beyond it, a hole is unreachable
    max_iters: int = field(default=12, metadata=rule(ge=1, le=MAX_ITERS))  # LM iterations per start
    # initial Marquardt damping: small, so a start near a solution takes Gauss-Newton steps (2 from a
    # network answer); it grows tenfold on every rejected step, so far starts stay safe
    damping: float = field(default=1e-5, metadata=rule(gt=0))
    margin: float = field(default=0.002, metadata=rule(ge=0))  # m kept beyond each safety distance
    guard: float = field(default=0.1, metadata=rule(gt=0))  # m: clearances this far above are not re-measured each step
    clearance_weight: float = field(default=1.0, metadata=rule(gt=0))
    perturbed_starts: int = field(default=8, metadata=rule(ge=0, le=MAX_STARTS))
    random_starts: int = field(default=16, metadata=rule(ge=0, le=MAX_STARTS))
    deep_starts: int = field(default=128, metadata=rule(ge=0, le=MAX_STARTS))  # last resort: many random starts ...
    deep_iters: int = field(default=30, metadata=rule(ge=1, le=MAX_ITERS))  # ... with a longer budget each
    perturb: float = field(default=0.05, metadata=rule(gt=0))  # start noise, fraction of each joint's range
    seed: int = field(default=0, metadata=rule(ge=0, le=SEED_MAX))
    # among ok solutions of a hole: the largest clearance, or the nearest to the start (least joint motion)
    prefer: str = field(default="clearance", metadata=rule(choices=("clearance", "start")))

    def __post_init__(self):
        if self.reach_tol_mm < self.tol_mm:
            raise ConfigError(f"hybrid: reach_tol_mm = {self.reach_tol_mm} must be >= tol_mm = {self.tol_mm}")


@dataclass
class Candidates:
    """Refined joints of one or more starts per hole, with what the status rules need; every field
    has the candidates along its first dimension (or the first two, hole-major, once grouped)."""

    q: torch.Tensor  # (N, n_joints)
    hole_error: torch.Tensor  # (N,) m
    clearances: torch.Tensor  # (N, 4) m, in SAFETY_KINDS order
    iterations: torch.Tensor  # (N,)
    residual: torch.Tensor  # (N, 6) pose6(q) - target, m

    FIELDS = ("q", "hole_error", "clearances", "iterations", "residual")

    def map(self, f) -> Candidates:
        return Candidates(*(f(getattr(self, name)) for name in self.FIELDS))

    def take(self, index) -> Candidates:
        return self.map(lambda t: t[index])

    def put(self, index, other: Candidates) -> None:
        for name in self.FIELDS:
            getattr(self, name)[index] = getattr(other, name)

    @staticmethod
    def per_hole(groups: list[Candidates], holes: int) -> Candidates:
        """Candidate sets of the same holes (each hole-major, ``holes * k_i``) side by side, flat."""
        return Candidates(*(torch.cat([getattr(g, name).reshape(holes, -1, *getattr(g, name).shape[1:])
                                       for g in groups], dim=1).flatten(0, 1) for name in Candidates.FIELDS))


@dataclass(frozen=True)
class BoomObstacle:
    """Another boom of the rig standing still: ``pair`` has the solved boom as its boom ``a``; ``frames``
    are the other boom's frames in the rig frame, ``(F, 4, 4)`` for every hole or ``(H, F, 4, 4)`` one
    stand per hole (:meth:`pipeline.geometry.rig.MountedBoom.frames`)."""

    pair: BoomPair
    frames: torch.Tensor
    name: str = "other boom"


class HybridSolver(Solver):
    name = "hybrid"

    def __init__(self, boom, safety: SafetyModel, init: Solver | None, settings: HybridSettings = HybridSettings(),
                 name: str = "hybrid", start_box: tuple[torch.Tensor, torch.Tensor] | None = None,
                 base: Sequence[float] | None = None):
        super().__init__(boom)
        if safety.boom is not boom:
            raise InputError(f"{name}: the safety model belongs to boom '{safety.boom.name}', not '{boom.name}'")
        self.safety, self.init, self.s, self.name = safety, init, settings, name
        self.space = JointSpace(boom)
        span = self.space.upper - self.space.lower
        self.wraps = self.space.revolute & (span >= 2 * math.pi - 1e-9)  # full-turn joints
        self.project = projector(self.space.lower, self.space.upper, self.wraps)
        # random starts: within the working box (the postures rigs use) where given, else the full ranges
        lo, hi = start_box if start_box is not None else (self.space.full(self.space.lower[None])[0],
                                                          self.space.full(self.space.upper[None])[0])
        self.start_lo, self.start_hi = lo[self.space.free].double(), hi[self.space.free].double()
        # a rig's boom: its base in the rig frame (m); frames, targets and clearances are in the rig frame
        self.base = None if base is None else torch.tensor([float(v) for v in base], dtype=torch.float64)
        if self.base is not None and self.base.shape != (3,):
            raise InputError(f"{name}: base = {list(base)!r}: expected [x, y, z] (m)")

    def _frames(self, q: torch.Tensor) -> torch.Tensor:
        frames = self.boom.frames(q)
        return frames if self.base is None else translate_frames(frames, self.base.to(frames))

    # ------------------------------------------------------------------ one LM run per start
    def _clearances(self, frames: torch.Tensor, others: Sequence = ()) -> torch.Tensor:
        """``(B, 4 + k)``: the four safety clearances, then one boom-boom clearance per ``(pair, frames (B, ...))``."""
        values = self.safety.clearances_from_frames(frames)
        return torch.stack([values[k] for k in SAFETY_KINDS] + [pair.clearance(frames, f) for pair, f in others],
                           dim=-1)

    def _rows(self, x: torch.Tensor, target: torch.Tensor, c_prev: torch.Tensor | None, others: Sequence = ()):
        """Stacked residual ``(B, m)``, its Jacobian ``(B, m, n)``, hole error ``(B,)``, clearances
        ``(B, 4)`` and whether they were measured at ``x`` (``(B,)``).

        ``c_prev`` None: pose rows only, clearances left unmeasured (NaN). Otherwise the clearances are
        measured only where the last measurement ``c_prev`` was within ``guard`` of a safety distance:
        one refinement step moves the boom by millimetres, so a boom far from every surface stays clear
        and pays for no clearance evaluation; every answer's clearances are measured again at the end.
        Clearance gradients are computed only where a clearance row is active (below ``margin``).
        ``others``: ``(pair, frames (B, F, 4, 4))`` per standing boom, each adding a boom-boom column."""
        s, n = self.s, self.space.n
        frames = self._frames(self.space.full(x))
        r = self.boom.pose6_from_frames(frames) - target
        J = self.boom.pose6_jacobian(frames)[..., self.space.free]
        hole = 0.5 * (r[:, :3].norm(dim=-1) + r[:, 3:].norm(dim=-1))
        if c_prev is None:
            unmeasured = torch.full((len(x), len(SAFETY_KINDS) + len(others)), math.nan, dtype=r.dtype, device=r.device)
            return r, J, hole, unmeasured, torch.zeros_like(hole, dtype=torch.bool)
        fresh = c_prev.min(dim=-1).values < s.guard
        c = c_prev.clone()
        near = fresh.nonzero().flatten()
        if len(near):
            c[near] = self._clearances(frames[near], [(p, f[near]) for p, f in others])
        active = c < s.margin
        w = s.clearance_weight * active.to(c.dtype)
        G = torch.zeros(*c.shape, n, dtype=c.dtype, device=c.device)
        rows = active.any(dim=-1).nonzero().flatten()
        if len(rows):
            _, grads = self.safety.clearances_with_jacobians(frames[rows])
            g = [grads[k] for k in SAFETY_KINDS]
            g += [p.clearance_with_jacobians(frames[rows], f[rows])[1] for p, f in others]  # w.r.t. this boom
            G[rows] = torch.stack(g, dim=-2)[..., self.space.free]
        r = torch.cat([r, w * (c - s.margin)], dim=-1)
        J = torch.cat([J, w.unsqueeze(-1) * G], dim=-2)
        return r, J, hole, c, fresh

    def refine(self, q0: torch.Tensor, target: torch.Tensor, use_safety: bool,
               max_iters: int | None = None, owner: torch.Tensor | None = None, others: Sequence = ()) -> Candidates:
        """Levenberg-Marquardt from ``q0 (N, n_joints)`` towards ``target (N, 6)``; each start stops
        on its own once exact (and, with ``use_safety``, clear), so the batch shrinks as it goes.
        ``owner (N,)``: which hole each start serves; once one start of a hole is done, the hole's
        other starts stop where they are (one ok answer is what a hole needs).
        ``others``: ``(pair, frames (N, F, 4, 4))`` per standing boom, one stand per start.
        The returned clearances are measured at the returned joints, always."""
        s = self.s
        max_iters = s.max_iters if max_iters is None else max_iters
        stop_tol = 1e-2 * s.tol_mm / 1000  # iterate well below the status tolerance: converged, not borderline
        tgt = target.double()
        measure_all = torch.full((len(q0), len(SAFETY_KINDS) + len(others)), -math.inf, dtype=torch.float64,
                                 device=q0.device)

        def evaluate(x, rows, c_prev) -> Evaluation:
            r, J, hole, c, fresh = self._rows(x, tgt[rows], c_prev, [(p, f[rows]) for p, f in others])
            return Evaluation(r, J, {"hole": hole, "c": c, "fresh": fresh})

        def fun(x, rows, current: Evaluation | None) -> Evaluation:
            # at the start every clearance is measured; later the trial reuses the current point's clearances
            if not use_safety:
                return evaluate(x, rows, None)
            return evaluate(x, rows, measure_all[rows] if current is None else current.extra["c"])

        def done(x, ev: Evaluation, rows) -> tuple[torch.Tensor, Evaluation | None]:
            e = ev.extra
            finished = (e["hole"] <= stop_tol) & ((e["c"] >= 0).all(-1) if use_safety else True)
            if use_safety and (finished & ~e["fresh"]).any():  # exact on clearances measured earlier: measure
                redo = (finished & ~e["fresh"]).nonzero().flatten()  # them here, so a start found unclear goes on
                ev.put(redo, evaluate(x[redo], rows[redo], measure_all[rows[redo]]))
                return (e["hole"] <= stop_tol) & (e["c"] >= 0).all(-1), ev
            return finished, None

        out = least_squares(fun, self.project(q0[:, self.space.free].double()), damping=Damping(initial=s.damping),
                            max_trials=max_iters, done=done, groups=owner, project=self.project)
        x_out, extra = out.x, out.evaluation.extra
        r_out, c_out = out.evaluation.r[:, :6], extra["c"]
        stale = (~extra["fresh"]).nonzero().flatten()
        if len(stale):  # the answer's own clearances, wherever the loop reused older ones
            c_out[stale] = self._clearances(self._frames(self.space.full(x_out[stale])),
                                            [(p, f[stale]) for p, f in others])
        hole_out = 0.5 * (r_out[:, :3].norm(dim=-1) + r_out[:, 3:].norm(dim=-1))
        return Candidates(self.space.full(x_out), hole_out, c_out, out.trials, r_out)

    # ------------------------------------------------------------------ statuses
    def rank(self, cand: Candidates, reference: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Status index (into STATUSES) and a score to minimise, per candidate: ok prefers the
        largest clearance (or, with ``prefer: start``, the least motion from ``reference``, in
        fractions of each joint's range), inexact the smallest error, unsafe an exact one first and then
        the smallest violation, unreachable the smallest error."""
        tol, reach = self.s.tol_mm / 1000, self.s.reach_tol_mm / 1000
        worst = cand.clearances.min(dim=-1).values
        exact, clear, reached = cand.hole_error <= tol, worst >= 0, cand.hole_error <= reach
        status = torch.full_like(cand.iterations, 3)  # unreachable: not within reach_tol, whatever the collisions
        # reached within reach_tol but colliding is unsafe, not unreachable (the pose can be reached)
        status = torch.where(reached & ~clear, torch.full_like(status, 2), status)
        status = torch.where(clear & reached, torch.full_like(status, 1), status)
        status = torch.where(exact & clear, torch.full_like(status, 0), status)
        # among unsafe candidates an exact one first (as before), then the smallest violation
        key = torch.where(status == 0, -worst.clamp(-10, 10), cand.hole_error.clamp(max=1e3))
        key = torch.where(status == 2, -worst.clamp(-10, 10) + 100.0 * (~exact).double(), key)
        if self.s.prefer == "start" and reference is not None:
            span = (self.space.upper - self.space.lower).to(cand.q)
            motion = (((cand.q - reference)[:, self.space.free] / span) ** 2).sum(-1)
            key = torch.where(status == 0, motion, key)
        return status, status.double() * 1e6 + key

    def best_of(self, cand: Candidates, holes: int, reference: torch.Tensor) -> tuple[Candidates, torch.Tensor]:
        """The best of ``K`` candidates per hole (laid out hole-major, ``holes * K``); ``reference``
        ``(holes, n_joints)`` is each hole's start. Iterations add up over a hole's candidates."""
        k = len(cand.q) // holes
        status, score = self.rank(cand, reference.repeat_interleave(k, dim=0))
        pick = score.reshape(holes, k).argmin(dim=1) + torch.arange(holes, device=score.device) * k
        best = cand.take(pick)
        best.iterations = cand.iterations.reshape(holes, k).sum(dim=1)
        return best, status[pick]

    def starts(self, q_net: torch.Tensor, kind: str) -> torch.Tensor:
        """``(holes, K, n_joints)`` extra starts: ``perturbed`` network answers, or ``random`` / ``deep``
        joint vectors (``random_starts`` / ``deep_starts`` of them) within the start box. The draws come
        from a seeded CPU generator on any device, so a GPU solve tries the same starts as the CPU one."""
        s, space = self.s, self.space
        g = torch.Generator().manual_seed(s.seed + ("perturbed", "random", "deep").index(kind))
        H, cpu = len(q_net), torch.device("cpu")
        if kind == "perturbed":
            noise = torch.randn(H, s.perturbed_starts, space.n, generator=g, dtype=torch.float64, device=cpu)
            x = q_net[:, space.free].unsqueeze(1) + (s.perturb * (space.upper - space.lower) * noise).to(q_net)
        else:
            k = s.random_starts if kind == "random" else s.deep_starts
            u = torch.rand(H, k, space.n, generator=g, dtype=torch.float64, device=cpu)
            x = (self.start_lo + u * (self.start_hi - self.start_lo)).to(q_net)
        return space.full(self.project(x))

    def _try(self, best: Candidates, status: torch.Tensor, todo: torch.Tensor, starts: torch.Tensor,
             pose: torch.Tensor, reference: torch.Tensor, use_safety: bool, max_iters: int | None = None,
             others: Sequence = ()) -> None:
        """Refine ``starts (len(todo), K, n)`` of the holes ``todo`` in one batch; each hole keeps the
        best of its current answer and the new candidates (in place)."""
        H, K, n = starts.shape
        if H == 0 or K == 0:
            return
        new = self.refine(starts.reshape(H * K, n), pose[todo].repeat_interleave(K, dim=0), use_safety, max_iters,
                          owner=torch.arange(H, device=starts.device).repeat_interleave(K),
                          others=[(p, f[todo].repeat_interleave(K, dim=0)) for p, f in others])
        chosen, chosen_status = self.best_of(Candidates.per_hole([best.take(todo), new], H), H, reference[todo])
        best.put(todo, chosen)
        status[todo] = chosen_status

    def postures(self, targets: Targets, obstacles: Sequence[BoomObstacle] = (), starts: int = 32,
                 seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
        """Other postures of each hole: ``starts`` random starts per hole in the start box, each refined
        on its own with the safety rows (``obstacles`` standing), as ``(H, starts, n_joints)`` joints and
        ``(H, starts)`` whether each is ok (exact and clear). The chain is redundant (8 joints for a 5-D
        hole), so starts in different branches (feed side, q4 / q7) end in different ok solutions; the
        round chooses among them (:mod:`pipeline.round.postures`). Seeded: the same starts on any device."""
        if not isinstance(targets, HoleTargets):
            raise InputError(f"{self.name}: solves holes (HoleTargets), got {type(targets).__name__}")
        with torch.inference_mode():
            pose = self.consistent(targets.pose.double())
            H, n = len(pose), self.space.n
            g = torch.Generator().manual_seed(int(seed))
            u = torch.rand(H, starts, n, generator=g, dtype=torch.float64)
            x = self.space.full(self.project((self.start_lo + u * (self.start_hi - self.start_lo)).to(pose)))
            others = self._obstacles(obstacles, H)
            cand = self.refine(x.reshape(H * starts, -1), pose.repeat_interleave(starts, dim=0), use_safety=True,
                               others=[(p, f.repeat_interleave(starts, dim=0)) for p, f in others])
            status, _ = self.rank(cand)
        return cand.q.reshape(H, starts, -1).clone(), (status == 0).reshape(H, starts).clone()

    # ------------------------------------------------------------------ the solve
    def consistent(self, pose: torch.Tensor) -> torch.Tensor:
        """The targets with each preview point at exactly the boom's preview depth from its collar,
        along the hole: the only poses the chain can reach exactly. A target whose two points are
        off by rounding (float32 input, a plan written to the millimetre) would otherwise leave a
        residual that no step removes, and every hole would run to ``max_iters``."""
        collar, axis = pose[:, :3], pose[:, 3:] - pose[:, :3]
        length = axis.norm(dim=-1, keepdim=True)
        preview = collar + self.boom.preview_depth * axis / length.clamp_min(1e-12)
        return torch.cat([collar, torch.where(length > 1e-9, preview, pose[:, 3:])], dim=-1)

    def _obstacles(self, obstacles: Sequence[BoomObstacle], holes: int) -> list:
        """``(pair, frames (holes, F, 4, 4))`` per obstacle, checked."""
        out = []
        for o in obstacles:
            if not isinstance(o, BoomObstacle) or o.pair.a is not self.boom:
                raise InputError(f"{self.name}: obstacle {getattr(o, 'name', o)!r}: expected a BoomObstacle whose "
                                 f"pair has this solver's boom '{self.boom.name}' as its boom a")
            f = o.frames.to(torch.float64)
            if f.ndim == 3:
                f = f.expand(holes, *f.shape)
            if f.ndim != 4 or f.shape[0] != holes or f.shape[-2:] != (4, 4):
                raise InputError(f"{self.name}: obstacle '{o.name}': frames of shape {tuple(o.frames.shape)}; "
                                 f"expected (F, 4, 4) or ({holes}, F, 4, 4)")
            out.append((o.pair, f))
        return out

    def solve(self, targets: Targets, obstacles: Sequence[BoomObstacle] = (),
              start: torch.Tensor | None = None) -> SolveResult:
        """First the network's answers, refined on the pose alone: a hole whose answer is then exact
        and clear by at least ``margin`` is done (most holes: one clearance evaluation each). The
        others are refined from the network's answer with the safety rows; for those still not ok:
        perturbed starts, random starts, many random starts with a longer budget, and finally random
        starts without the safety rows (can the pose be reached at all?). Each stage sees only the
        holes the previous ones left, so the batch pays for the hard holes alone.

        ``targets`` are in the rig frame when the solver has a ``base`` (the network, trained in the boom's
        base frame, sees them shifted back). ``obstacles``: other booms standing, as obstacles (their
        boom-boom clearance is ``clearances["boom"]``, the smallest over them). ``start (H, n_joints)``:
        each hole's first start instead of the network's answer (e.g. the previous hole's joints); with
        ``prefer: start`` the ok solution nearest to it is kept, so redundancy serves the next move."""
        if not isinstance(targets, HoleTargets):
            raise InputError(f"{self.name}: solves holes (HoleTargets), got {type(targets).__name__}")
        if len(targets) == 0:
            raise InputError(f"{self.name}: no targets to solve")
        clock = time.perf_counter()
        with torch.inference_mode():  # no autograd bookkeeping: a fifth of a single hole's time
            pose = targets.pose.double()
            target = self.consistent(pose)
            others = self._obstacles(obstacles, len(pose))
            # the first starts on the targets' device: a solve runs where its holes are (CPU or CUDA)
            if start is not None:
                q_net = self.boom.check_joints(start, "start").to(pose).expand(len(pose), -1).clone()
            elif self.init is not None:
                own = targets if self.base is None else HoleTargets(pose - self.base.to(pose).repeat(2), targets.depth)
                q_net = self.init.joints(own).to(pose)
            else:
                q_net = self.space.full((0.5 * (self.space.lower + self.space.upper)).to(pose).expand(len(pose), -1))
            best = self.refine(q_net, target, use_safety=False, others=others)
            status, _ = self.rank(best)
            spare = best.clearances.min(dim=-1).values >= self.s.margin
            todo = ((status != 0) | ~spare).nonzero().flatten()
            self._try(best, status, todo, q_net[todo].unsqueeze(1), target, q_net, use_safety=True, others=others)
            todo = (status != 0).nonzero().flatten()
            if len(todo):
                self._try(best, status, todo, self.starts(q_net[todo], "perturbed"), target, q_net, use_safety=True,
                          others=others)
                todo = (status != 0).nonzero().flatten()
                self._try(best, status, todo, self.starts(q_net[todo], "random"), target, q_net, use_safety=True,
                          others=others)
                todo = (status != 0).nonzero().flatten()
                self._try(best, status, todo, self.starts(q_net[todo], "deep"), target, q_net, use_safety=True,
                          max_iters=self.s.deep_iters, others=others)
                todo = (status != 0).nonzero().flatten()
                self._try(best, status, todo, self.starts(q_net[todo], "random"), target, q_net, use_safety=False,
                          others=others)
        wall = time.perf_counter() - clock
        best = best.map(torch.clone)  # ordinary tensors again: callers may use them with autograd
        target, pose = target.clone(), pose.clone()
        err = pose_errors(target + best.residual, pose)  # the reached pose against the target as given
        errors = {"position": err["start"], "orientation": err["direction"], "preview": err["preview"],
                  "hole": err["hole"]}
        clearances = {k: best.clearances[:, i] for i, k in enumerate(SAFETY_KINDS)}
        if others:  # the nearest standing boom
            clearances["boom"] = best.clearances[:, len(SAFETY_KINDS):].min(dim=-1).values
        return SolveResult(best.q, errors, best.iterations, wall,
                           status=[STATUSES[i] for i in status.tolist()], clearances=clearances)
