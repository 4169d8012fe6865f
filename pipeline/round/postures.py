"""Each hole's posture, chosen with the route: alternatives, the choice along routes, the bound.

The jumbo8 chain is redundant (8 joints for a 5-D hole), so a hole has many exact, clear joint
solutions: the feed on one side of the boom head or the other, the q4 / q7 branches. The reach table
keeps one per hole and boom (the hybrid's first ok answer, the largest clearance), and that one decides
where the arm is, so which straight moves break self or tunnel clearance (detours) and which pairs of
holes of two booms conflict standing (waits). Here:

1. :func:`posture_alternatives`: per hole and boom up to ``k`` distinct ok solutions, the reach
   table's first, then the ok answers of random starts (:meth:`HybridSolver.postures`, the other booms
   at park) farthest from those kept (farthest-point selection in move time), each at least ``gap_s``
   of move time from every other;
2. :func:`choose_postures`: for fixed routes, one alternative per hole of each boom's route, chosen
   exactly (a shortest path through the route's layers of alternatives, the Viterbi recursion) to
   minimise the boom's move time plus ``conflict_s`` per configuration of another boom, standing or at
   either end of its move, that the alternative breaks d_boom with while the hole is entered and drilled
   (the other booms' times from the timeline of the routes, their postures as chosen so far: one pass,
   boom by boom);
3. :func:`posture_bound`: the reference's lower bound with each move the least over the alternatives, so it
   stays a bound whatever the planner chooses.

The planner (:func:`pipeline.round.from_plan.schedule_round`) times the seeds on the reach table's
postures, chooses along the best round's routes, plans again from those postures (routing included, the
previous round's routes a candidate), and repeats along the better round's routes while that is better,
up to ``round.posture_rounds`` times (docs/round.md, "Postures").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from pipeline.motion.checks import check_straight_moves
from pipeline.motion.path import unwrapped
from pipeline.motion.timing import JointLimits, move_time
from pipeline.plans.reach import Reach, parked_others
from pipeline.round.bounds import bound_from
from pipeline.round.problem import Instance
from pipeline.round.timeline import Timeline, segments
from pipeline.solvers.base import HoleTargets

D = torch.float64


@dataclass(frozen=True)
class Postures:
    """Per boom ``q[b] (H, K, n)`` joint solutions of each hole, column 0 the reach table's; ``ok (B, H,
    K)``: alternative k is an ok solution (column 0: the reach table's status). Rows that are not ok
    hold any values."""

    q: list[torch.Tensor]
    ok: np.ndarray

    @property
    def k(self) -> int:
        return int(self.ok.shape[2])

    def counts(self) -> dict:
        """How many holes have 1, 2, ... ok alternatives, per boom (holes the boom can drill)."""
        n = self.ok.sum(axis=2)
        return {b: {int(c): int((n[b] == c).sum()) for c in range(1, self.k + 1)} for b in range(len(self.q))}


def posture_alternatives(plan, rig, solvers: Sequence, reach: Reach, limits: Sequence[JointLimits], k: int = 3,
                         starts: int = 32, gap_s: float = 2.0, seed: int = 0) -> Postures:
    """Up to ``k`` distinct ok solutions per hole and boom (module docstring, step 1)."""
    qs, oks = [], []
    for b, (mount, solver) in enumerate(zip(rig.booms, solvers, strict=True)):
        res = reach.results[mount.name]
        q0 = res.q.detach().to(D).cpu()
        ok0 = torch.tensor([s == "ok" for s in res.status])
        q, ok = q0.new_zeros(len(q0), 0, q0.shape[1]), torch.zeros(len(q0), 0, dtype=torch.bool)
        if k > 1 and starts > 0:
            targets = HoleTargets(plan.poses(mount.boom.preview_depth), mount.boom.preview_depth)
            q, ok = solver.postures(targets, parked_others(rig, b), starts, seed + b)
        qs_b, ok_b = farthest(q0, ok0, q.to(D).cpu(), ok.cpu(), limits[b], k, gap_s)
        qs.append(qs_b)
        oks.append(ok_b.numpy())
    return Postures(qs, np.stack(oks))


def round_postures(plan, rig, solvers: Sequence, reach: Reach, motions, settings) -> Postures | None:
    """The alternatives the round settings ask for (``round.postures`` > 1, a rig's boom solvers), or None."""
    if settings.postures <= 1 or settings.posture_starts == 0:
        return None
    return posture_alternatives(plan, rig, solvers, reach, [m.joints for m in motions], settings.postures,
                                settings.posture_starts, settings.posture_gap_s, settings.posture_seed)


def farthest(q0: torch.Tensor, ok0: torch.Tensor, q: torch.Tensor, ok: torch.Tensor, limits: JointLimits, k: int,
             gap_s: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(H, k, n)`` and ``(H, k)``: the first solution, then up to ``k - 1`` of the ok candidates ``q
    (H, S, n)``, each the farthest (in move time) from those kept and at least ``gap_s`` from each;
    a hole whose first solution is not ok keeps none of the others (the boom cannot drill it)."""
    H, n = q0.shape
    out, keep = q0.new_zeros(H, k, n), torch.zeros(H, k, dtype=torch.bool)
    out[:, 0], keep[:, 0] = q0, ok0
    if k == 1 or q.shape[1] == 0:
        return out, keep
    near = move_time(q0[:, None, :], q, limits)  # (H, S): move time to the nearest kept solution
    rows = torch.arange(H)
    for j in range(1, k):  # k is small (round.postures, 8): a loop over the kept count, every hole at once
        score = torch.where(ok & ok0[:, None] & (near >= gap_s), near, torch.full_like(near, -1.0))
        best, pick = score.max(dim=1)
        found = best >= 0
        out[:, j] = torch.where(found[:, None], q[rows, pick], q0)
        keep[:, j] = found
        near = torch.minimum(near, move_time(q[rows, pick][:, None, :], q, limits))
    return out, keep


def _concurrent(tl: Timeline, b: int, others: Sequence[int]) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Per other boom o: ``(o, positions, nodes)``, the pairs of a position in b's route and a node of o
    where o stands at the node, or moves from or to it, while b moves into that hole or stands at it
    (until b's next move starts)."""
    n = len(tl.routes[b])
    lo, hi = tl.move_start[b][:n], tl.move_start[b][1:n + 1]
    out = []
    for o in others:
        s = segments(tl, o)
        pos, seg = np.nonzero((s["t0"][None, :] < hi[:, None]) & (s["t1"][None, :] > lo[:, None]))
        pair = np.unique(np.stack([np.concatenate([pos, pos]), np.concatenate([s["u"][seg], s["v"][seg]])], axis=1),
                         axis=0)
        out.append((o, pair[:, 0], pair[:, 1]))
    return out


def choose_postures(inst: Instance, tl: Timeline, postures: Postures, joints: Sequence[torch.Tensor], rig,
                    limits: Sequence[JointLimits], conflict_s: float = 60.0, unclear_s: float = 30.0,
                    screen_m: float = 0.05) -> list[torch.Tensor]:
    """Per boom ``(H, n)``: ``joints`` (the instance's, the reach table's) with each hole of the boom's
    route in ``tl`` at the alternative the exact recursion of the module docstring (step 2) chooses;
    holes off the route keep theirs. ``unclear_s``: the price of a straight move that breaks self or
    tunnel clearance at the screen's samples (``screen_m`` of point travel): it would need a detour."""
    H = inst.n_holes
    chosen = [torch.as_tensor(q, dtype=D).clone() for q in joints]
    for b, route in enumerate(tl.routes):
        if not route:
            continue
        r = torch.as_tensor(route)
        cand = postures.q[b][r]  # (R, K, n)
        valid = torch.as_tensor(postures.ok[b][route])  # (R, K)
        unary = torch.zeros(valid.shape, dtype=D)
        for o, pos, node in _concurrent(tl, b, [o for o in range(len(tl.routes)) if o != b]):
            if not len(pos) or conflict_s == 0:
                continue
            park = rig.booms[o].park.to(D)
            qo = torch.cat([chosen[o], park[None]])[torch.as_tensor(node)]  # (P, n): o's configurations
            with torch.inference_mode():
                c = rig.boom_clearance(b, cand[torch.as_tensor(pos)], o, qo[:, None, :].expand(-1, cand.shape[1], -1))
            hits = torch.zeros(valid.shape, dtype=D).index_add_(0, torch.as_tensor(pos), (c < 0).to(D))
            unary += conflict_s * hits
        park = rig.booms[b].park.to(D)
        start = park if inst.start is None or inst.starts[b] == H else chosen[b][inst.starts[b]]
        extra = _unclear(rig, b, start, cand, valid, park, limits[b], screen_m, unclear_s)
        picks = _shortest_path(start, cand, valid, unary, park, limits[b], extra)
        chosen[b][r] = cand[torch.arange(len(route)), picks]
    return chosen


def _unclear(rig, b: int, start: torch.Tensor, cand: torch.Tensor, valid: torch.Tensor, park: torch.Tensor,
             limits: JointLimits, screen_m: float, price_s: float) -> tuple[torch.Tensor, ...] | None:
    """``price_s`` per straight move between consecutive layers (start -> layer 0 ``(K,)``, layer i-1 -> i
    ``(R-1, K, K)``, last -> park ``(K,)``) that is not clear of self and tunnel at the screen's samples;
    only moves between valid alternatives are screened, all in one batch."""
    if price_s == 0:
        return None
    R, K, n = cand.shape
    pairs = valid[:-1, :, None] & valid[1:, None, :]  # (R-1, K, K)
    i, ka, kb = pairs.nonzero(as_tuple=True)
    k0, kr = valid[0].nonzero().flatten(), valid[-1].nonzero().flatten()
    qa = torch.cat([start.expand(len(k0), n), cand[i, ka], cand[-1, kr]])
    qb = torch.cat([cand[0, k0], cand[i + 1, kb], park.expand(len(kr), n)])
    with torch.inference_mode():
        ok = check_straight_moves(rig, b, qa, unwrapped(qa, qb, limits), resolution=screen_m).clear(
            kinds=("self", "tunnel"))
    bad = price_s * (~ok).to(D)
    first, mid = torch.zeros(K, dtype=D), torch.zeros(R - 1, K, K, dtype=D)
    last = torch.zeros(K, dtype=D)
    first[k0] = bad[:len(k0)]
    mid[i, ka, kb] = bad[len(k0):len(k0) + len(i)]
    last[kr] = bad[len(k0) + len(i):]
    return first, mid, last


def _shortest_path(start: torch.Tensor, cand: torch.Tensor, valid: torch.Tensor, unary: torch.Tensor,
                   park: torch.Tensor, limits: JointLimits, extra=None) -> torch.Tensor:
    """``(R,)`` the alternative of each layer on the cheapest path start -> layer 0 -> ... -> park (move
    times, plus ``unary`` per alternative and ``extra`` per move: ``(first (K,), mid (R-1, K, K), last
    (K,))``; invalid alternatives never taken). Ties keep the lower index (the reach table's solution
    first). A route's layers are visited in order: the recursion is sequential."""
    K = cand.shape[1]
    first, mid, last = extra if extra is not None else (torch.zeros(K, dtype=D), None, torch.zeros(K, dtype=D))
    inf = torch.tensor(torch.inf, dtype=D)
    cost = torch.where(valid[0], move_time(start[None], cand[0], limits) + unary[0] + first, inf)
    back = []
    for i in range(1, len(cand)):
        step = cost[:, None] + move_time(cand[i - 1][:, None, :], cand[i][None, :, :], limits)
        if mid is not None:
            step = step + mid[i - 1]
        best, arg = step.min(dim=0)
        cost = torch.where(valid[i], best + unary[i], inf)
        back.append(arg)
    cost = cost + move_time(cand[-1], park[None], limits) + last
    k = int(cost.argmin())
    picks = [k]
    for arg in reversed(back):
        k = int(arg[k])
        picks.append(k)
    return torch.tensor(picks[::-1])


def posture_bound(inst: Instance, postures: Postures, limits: Sequence[JointLimits], rig) -> float:
    """The reference's lower bound (:func:`pipeline.round.bounds.bound_from`) with every move the least over
    all alternatives of its two holes: a bound on any round that drills each hole at one of them.
    Straight-line move times: a detour is never shorter."""
    B, H, K = postures.ok.shape
    first, into_by, home = (np.full((B, H), np.inf) for _ in range(3))
    for b in range(B):
        park = rig.booms[b].park.to(D)
        q = postures.q[b].reshape(H * K, -1)
        ok = torch.as_tensor(postures.ok[b].reshape(H * K)) & torch.as_tensor(inst.reach[b]).repeat_interleave(K)
        start = park if inst.start is None or inst.starts[b] == H else torch.as_tensor(postures.q[b][inst.starts[b], 0])
        f = torch.where(ok, move_time(start[None], q, limits[b]), torch.inf).reshape(H, K)
        back = torch.where(ok, move_time(q, park[None], limits[b]), torch.inf).reshape(H, K)
        mv = move_time(q[:, None, :], q[None, :, :], limits[b])  # (HK, HK)
        hole = torch.arange(H).repeat_interleave(K)
        mv = torch.where(ok[:, None] & ok[None, :] & (hole[:, None] != hole[None, :]), mv, torch.inf)
        entry = torch.minimum(mv.min(dim=0).values.reshape(H, K), f)
        first[b], into_by[b], home[b] = (t.min(dim=1).values.numpy() for t in (f, entry, back))
    return bound_from(inst.reach, inst.drill_s, first, into_by, home)
