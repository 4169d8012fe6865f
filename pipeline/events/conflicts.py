"""Which pairs of actions of two booms conflict: can come within d_boom (plus the planner's margin) at
*some* relative timing.

An action's *sweep* is every configuration it passes through: a move's path as the oracle moves it
(the synchronised straight line, or the move's detour: straight joint-space segments between
waypoints), endpoints included; a drill is one configuration. Two actions conflict when the smallest
boom-boom clearance (m, less d_boom) between any configuration of one sweep and any of the other is
below the oracle's ``margin`` (the scan flags moving pairs below it; using it for every pair is
conservative).

**Certified, not merely sampled.** Each straight segment ``start + s step`` is sampled at equal steps
of s such that no point of the boom moves more than ``sample_m`` between samples (``travel(step) /
n <= sample_m``, :func:`pipeline.motion.path.travel` with the lever arms of
:func:`pipeline.motion.checks.lever_arms`); the travel bound is linear in s, so every configuration is
within half a spacing ``delta / 2`` of a sample, point by point. Capsule axes are segments between
two points that each move at most that much, so capsule distances change by at most ``delta_a / 2 +
delta_b / 2``. A pair is counted as conflicting when its sampled minimum less that is below the
margin: a false conflict only adds an interlock, a missed one cannot happen.

**Batched.** Per sample a box of its capsule axes inflated by the boom's largest radius (the capsule
surfaces lie inside); per action the box of its samples' boxes. The distance between two boxes (the
norm of the per-axis gaps) is at most the capsule surfaces' distance, so action pairs and then sample
pairs whose boxes are farther apart than ``d_boom + margin + (delta_a + delta_b) / 2`` cannot
conflict and are never evaluated. The rest: all-pairs capsule distances (:meth:`BoomPair.distances`
semantics: the clamped segment distance of the capsule axes less both radii, on precomputed rig-frame
capsule ends) in chunks of sample pairs, reduced per action pair with a scatter-min, coarse to fine
(``STRIDES``: every 16th sample of each sweep, every 4th, all; with stride s the spacing is s delta,
so the same certificate holds at each level): a pair whose sampled minimum is already below the
margin (a real conflict) or whose certified floor is above it is decided and not sampled finer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from pipeline.events.actions import Actions
from pipeline.geometry.compiled_rig import indexed_clearances
from pipeline.motion.path import travel
from pipeline.motion.timing import profile

D = torch.float64
INDEX_CHUNK = 1_000_000  # sample pairs box-tested at once
EVAL_CHUNK = 65536  # sample pairs whose capsule distances are evaluated at once
STRIDES = (16, 4, 1)  # coarse to fine: a pair decided on every 16th sample is not sampled finer


@dataclass(frozen=True)
class Sweep:
    """One boom's sampled sweeps: configurations ``q (S, n)``, the action of each (global number),
    per action its sample spacing ``delta`` (m of point travel; 0 for one configuration), and boxes."""

    q: torch.Tensor
    owner: np.ndarray
    delta: dict[int, float]
    ends: torch.Tensor  # (S, bodies, 2, 3) capsule axis ends, rig frame
    radius: torch.Tensor  # (bodies,)
    lo: torch.Tensor  # (S, 3) box of the sample's capsules (axes' box widened by the largest radius)
    hi: torch.Tensor


@dataclass(frozen=True)
class Conflicts:
    """Action pairs ``(i, j)`` (global numbers, boom of i < boom of j) whose boxes came close: their
    smallest sampled clearance ``least`` (inf: every sample pair was ruled out by boxes), the certified
    lower bound ``lower = least - (delta_i + delta_j) / 2`` and whether they conflict (``lower <
    margin``). Pairs not listed cannot conflict."""

    pairs: np.ndarray
    least: np.ndarray
    lower: np.ndarray
    conflict: np.ndarray
    margin: float
    evaluations: int

    @property
    def conflicting(self) -> np.ndarray:
        return self.pairs[self.conflict]


def _segments(acts: Actions, oracle, b: int):
    """Straight joint-space segments ``start, step (S, n)`` of boom b's actions and their owners."""
    q = oracle.joints[b]
    ks = np.flatnonzero(acts.boom == b)
    starts, steps, owner = [], [], []
    drills = ks[acts.is_drill[ks]]
    if len(drills):
        starts.append(q[torch.as_tensor(acts.hole[drills])])
        steps.append(torch.zeros_like(starts[-1]))
        owner.append(drills)
    moves = ks[~acts.is_drill[ks]]
    detour = np.array([oracle.detour(b, int(acts.src[k]), int(acts.dst[k])) is not None for k in moves], bool)
    plain = moves[~detour]
    if len(plain):
        prof = profile(q[torch.as_tensor(acts.src[plain])], q[torch.as_tensor(acts.dst[plain])], oracle.limits[b])
        starts.append(prof.start)
        steps.append(prof.step)
        owner.append(plain)
    for k in moves[detour]:  # few: a detour is a path of several segments
        seg = oracle.detour(b, int(acts.src[k]), int(acts.dst[k])).segments
        starts.append(seg.start.to(D))
        steps.append(seg.step.to(D))
        owner.append(np.full(seg.start.shape[0], k))
    n = q.shape[1]
    if not starts:
        return torch.zeros(0, n, dtype=D), torch.zeros(0, n, dtype=D), np.zeros(0, int)
    owner = np.concatenate(owner)
    by = np.argsort(owner, kind="stable")  # grouped by action, in order (a detour's segments in path order)
    t = torch.as_tensor(by)
    return torch.cat(starts)[t], torch.cat(steps)[t], owner[by]


def sweep(acts: Actions, oracle, b: int) -> Sweep:
    """Boom b's sweeps sampled at most ``oracle.sample_m`` of point travel apart (module docstring)."""
    start, step, seg_owner = _segments(acts, oracle, b)
    R = travel(step, oracle.levers[b].to(D))
    n = torch.ceil(R / oracle.sample_m).long()  # steps per segment (0: one configuration)
    spacing = torch.where(n > 0, R / n.clamp_min(1), torch.zeros_like(R))
    which = torch.repeat_interleave(torch.arange(len(n)), n + 1)
    first = torch.cumsum(n + 1, 0) - (n + 1)
    k = torch.arange(len(which)) - first[which]
    s = (k.to(D) / n[which].clamp_min(1).to(D))[:, None]
    q = start[which] + s * step[which]
    owner = seg_owner[which.numpy()]
    delta: dict[int, float] = {}
    for a, d in zip(seg_owner.tolist(), spacing.tolist(), strict=True):
        delta[a] = max(delta.get(a, 0.0), d)
    mounted = oracle.rig.booms[b]
    with torch.inference_mode():
        frames = mounted.frames(q)
        ends = torch.stack([torch.stack(mounted.boom.capsule_ends(frames, name), -2) for name in mounted.boom.bodies],
                           -3)  # (S, bodies, 2, 3)
    radius = torch.tensor([body.radius for body in mounted.boom.bodies.values()], dtype=D)
    r = float(radius.max())
    return Sweep(q, owner, delta, ends, radius, ends.amin((-3, -2)) - r, ends.amax((-3, -2)) + r)


def _box_gap(lo_a, hi_a, lo_b, hi_b) -> torch.Tensor:
    """Euclidean distance between axis-aligned boxes (0 when they touch or overlap)."""
    g = torch.maximum(lo_b - hi_a, lo_a - hi_b).clamp_min(0)
    return torch.linalg.vector_norm(g, dim=-1)


def _clearance(sa: Sweep, xa: torch.Tensor, sb: Sweep, xb: torch.Tensor, d_boom: float) -> torch.Tensor:
    """Boom-boom clearance (m, less d_boom) of sample pairs: every capsule of a against every capsule
    of b, the clamped segment distance of their axes less both radii (as :class:`BoomPair`), by the
    compiled rig kernel (one pass over the pairs; torch's broadcast of every capsule pair was about a
    third of the tiny study's schedule stage)."""
    flat = lambda e: e.reshape(len(e), -1, 3).numpy()  # noqa: E731  (S, 2 bodies, 3): body i's ends at 2i, 2i+1
    c = indexed_clearances(flat(sa.ends), flat(sb.ends), xa.numpy(), xb.numpy(), sa.radius.numpy(),
                           sb.radius.numpy(), float(d_boom))
    return torch.from_numpy(c)


def _grouped(sw: Sweep, ids: np.ndarray):
    """Per action of ``ids`` (in order): its box, its first sample and its number of samples."""
    pos = {int(k): i for i, k in enumerate(ids)}
    idx = torch.as_tensor([pos[int(k)] for k in sw.owner], dtype=torch.long)
    lo = torch.full((len(ids), 3), np.inf, dtype=D).scatter_reduce(0, idx[:, None].expand(-1, 3), sw.lo, "amin")
    hi = torch.full((len(ids), 3), -np.inf, dtype=D).scatter_reduce(0, idx[:, None].expand(-1, 3), sw.hi, "amax")
    first = torch.searchsorted(idx, torch.arange(len(ids)))  # samples come grouped by action, in order
    count = torch.bincount(idx, minlength=len(ids))
    delta = torch.as_tensor([sw.delta[int(k)] for k in ids], dtype=D)
    return lo, hi, first, count, delta


def _level(sa, ga, pi, sb, gb, pj, stride: int, d_boom: float, margin: float):
    """Smallest clearance of every action pair (pi[p] of a, pj[p] of b) over every ``stride``-th sample
    of each (and its last), and the spacing (m of point travel) of that subsample, per side."""
    _, _, first_a, cnt_a, del_a = ga
    _, _, first_b, cnt_b, del_b = gb
    sub = lambda c: torch.where(c > 1, (c - 2) // stride + 2, torch.ones_like(c))  # noqa: E731  0, s, 2s, .., last
    na, nb = sub(cnt_a[pi]), sub(cnt_b[pj])
    half = (torch.minimum(torch.full_like(del_a[pi], stride), (cnt_a[pi] - 1).clamp_min(0).to(D)) * del_a[pi]
            + torch.minimum(torch.full_like(del_b[pj], stride), (cnt_b[pj] - 1).clamp_min(0).to(D)) * del_b[pj]) / 2
    thr = d_boom + margin + half
    least = torch.full((len(pi),), np.inf, dtype=D)
    sizes = na * nb
    ends = torch.cumsum(sizes, 0)
    evaluations, lo_p = 0, 0
    while lo_p < len(pi):  # groups of action pairs, about INDEX_CHUNK sample pairs each
        base = int(ends[lo_p - 1]) if lo_p else 0
        hi_p = max(lo_p + 1, int(torch.searchsorted(ends, base + INDEX_CHUNK, right=True)))
        grp = torch.arange(lo_p, hi_p)
        sz = sizes[grp]
        of = torch.repeat_interleave(grp, sz)
        local = torch.arange(int(sz.sum())) - torch.repeat_interleave(torch.cumsum(sz, 0) - sz, sz)
        m = nb[of]
        xa = first_a[pi[of]] + torch.minimum((local // m) * stride, cnt_a[pi[of]] - 1)
        xb = first_b[pj[of]] + torch.minimum((local % m) * stride, cnt_b[pj[of]] - 1)
        near = _box_gap(sa.lo[xa], sa.hi[xa], sb.lo[xb], sb.hi[xb]) < thr[of]
        of, xa, xb = of[near], xa[near], xb[near]
        for s in range(0, len(of), EVAL_CHUNK):
            sl = slice(s, s + EVAL_CHUNK)
            c = _clearance(sa, xa[sl], sb, xb[sl], d_boom)
            least = least.scatter_reduce(0, of[sl], c, "amin")
            evaluations += len(c)
        lo_p = hi_p
    return least, half, evaluations


def _keys(acts: Actions, oracle, ids: np.ndarray) -> list[tuple]:
    """What fixes an action's sweep: boom, kind, nodes, and whether its move is a detour."""
    out = []
    for k in ids:  # one tuple per action
        b, u, v, drill = int(acts.boom[k]), int(acts.src[k]), int(acts.dst[k]), bool(acts.is_drill[k])
        out.append((b, drill, u, v, (not drill) and oracle.detour(b, u, v) is not None))
    return out


def conflicts(acts: Actions, oracle, strides=STRIDES) -> Conflicts:
    """Every pair of actions of two different booms that may conflict (module docstring). A pair whose
    two sweeps were measured before (``oracle.sweep_pairs``: the same actions of an earlier round, e.g.
    the planned round of one handed on) takes that result; new results are added there."""
    rig, margin = oracle.rig, float(oracle.margin)
    known = oracle.sweep_pairs
    sweeps = {b: sweep(acts, oracle, b) for b in sorted(set(acts.boom.tolist()))}
    out, evaluations = [], 0
    booms = sorted(sweeps)
    for n_a, a in enumerate(booms):
        for b in booms[n_a + 1:]:
            sa, sb = sweeps[a], sweeps[b]
            d_boom = rig.pair(a, b).d_boom
            ids_a, ids_b = np.flatnonzero(acts.boom == a), np.flatnonzero(acts.boom == b)
            ga, gb = _grouped(sa, ids_a), _grouped(sb, ids_b)
            thr = d_boom + margin + (ga[4][:, None] + gb[4][None, :]) / 2
            gap = _box_gap(ga[0][:, None], ga[1][:, None], gb[0][None], gb[1][None])
            pi, pj = torch.nonzero(gap < thr, as_tuple=True)
            least = torch.full((len(pi),), np.inf, dtype=D)
            lower = torch.full((len(pi),), np.inf, dtype=D)
            ka, kb = _keys(acts, oracle, ids_a), _keys(acts, oracle, ids_b)
            keys = [(ka[i], kb[j]) for i, j in zip(pi.tolist(), pj.tolist(), strict=True)]
            hit = np.array([k in known for k in keys], bool)
            if hit.any():
                got = np.array([known[k] for k, h in zip(keys, hit, strict=True) if h], float).reshape(-1, 2)
                least[torch.as_tensor(hit)] = torch.as_tensor(got[:, 0], dtype=D)
                lower[torch.as_tensor(hit)] = torch.as_tensor(got[:, 1], dtype=D)
            open_ = torch.as_tensor(np.flatnonzero(~hit))
            for level, stride in enumerate(strides):
                if not len(open_):
                    break
                lst, half, n = _level(sa, ga, pi[open_], sb, gb, pj[open_], stride, d_boom, margin)
                evaluations += n
                least[open_] = torch.minimum(least[open_], lst)
                lower[open_] = lst - half
                # decided: a sampled pair below the margin (a real conflict), or a certified floor above it
                final = level == len(strides) - 1
                decided = torch.ones_like(lst, dtype=torch.bool) if final else (lst < margin) | (lst - half >= margin)
                open_ = open_[~decided]
            for n in np.flatnonzero(~hit):  # measured now: kept for the next round of the same actions
                known[keys[n]] = (float(least[n]), float(lower[n]))
            out.append((np.stack([ids_a[pi.numpy()], ids_b[pj.numpy()]], 1), least.numpy(), lower.numpy()))
    pairs = np.concatenate([o[0] for o in out]) if out else np.zeros((0, 2), int)
    least = np.concatenate([o[1] for o in out]) if out else np.zeros(0)
    lower = np.concatenate([o[2] for o in out]) if out else np.zeros(0)
    return Conflicts(pairs.astype(int), least, lower, lower < margin, margin, evaluations)
