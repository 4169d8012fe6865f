"""Boom-boom conflicts of timed segments, from the real kinematics (rig model, boom_pair, timing).

A segment of boom b is ``(t0, t1, u, v)``: standing at node u (``u == v``: a hole's joints, or its
park, index H) or moving from u to v, starting at t0: by the synchronised straight-line move of
:func:`pipeline.motion.timing.profile`, or by the boom's *detour* for u -> v when one was set
(:meth:`KinematicOracle.set_detour`: a :class:`pipeline.motion.path.Path` of rest-to-rest segments,
the retract or planned move of :func:`pipeline.motion.moves.plan_move`; :mod:`pipeline.round.detours`
sets them). The move's duration is ``move_s[b, u, v]`` of the instance, which holds the detour's. The timeline
asks :meth:`KinematicOracle.check` for batches of pairs of segments of two booms over the interval
where both run; the oracle answers, per pair, the first instant where d_boom breaks (inf if none) and
the smallest clearance it sampled.

Standing x standing needs one number per (boom a at node i, boom b at node j): :meth:`standing` is
the whole ``(H + 1, H + 1)`` matrix per boom pair, computed once (one batched call) and cached; most
pairs of a timeline are of this kind.

Pairs with a move are checked by conservative advancement at instants common to both booms. A point
of boom b moves at most at ``|ds/dt| * K_b <= peak * K_b`` with ``K_b = sum_i |step_i| * lever_i``
(``lever_i``: :func:`pipeline.motion.checks.lever_arms`, a bound on the distance of any capsule
point from joint i's axis; 1 for a prismatic joint; a detour's K is the largest over its segments).
So if the clearance is c at instant t, it stays at least ``floor`` until
``t + (c - floor) / (v_a + v_b)``: the next instant checked. ``floor = 2 traj_tol_m`` keeps the
trajectory file clear too (its linear interpolation keeps each boom within traj_tol_m of the plan).
A pair conflicts at the first checked instant whose clearance is below ``margin = sample_m / 2 +
floor``; above it every step is at least ``sample_m / 2 / (v_a + v_b)`` long (no point travels less
than sample_m / 4 between two checks), so the check ends. Far apart booms need few instants, close
ones many. Each round evaluates ``block`` instants per pair at once (spaced by the last step) and
advances over the run of them whose safe intervals join up. Standing pairs are exact (no motion,
rows exact): they conflict below 0. ``least`` reports the smallest clearance at the instants
checked (steps shrink near the minimum).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from pipeline.motion.checks import lever_arms
from pipeline.motion.path import Path
from pipeline.motion.timing import JointLimits, Profile, profile
from pipeline.round.compiled_oracle import advance

D = torch.float64


@runtime_checkable
class ConflictOracle(Protocol):
    """What the timeline needs of an oracle: the first conflict of pairs of segments (and, for the
    planner's fallbacks, the clearance of booms standing at nodes). :class:`KinematicOracle` is the
    rig's; tests plant simpler ones (a table of which nodes conflict). Only a kinematic oracle has a
    rig, so only it gets a move book (certified moves, detours) and the park screening."""

    def check(self, a: int, seg_a: dict, b: int, seg_b: dict, lo: np.ndarray, hi: np.ndarray): ...


class KinematicOracle:
    """Conflicts of two booms' segments, measured with the rig's boom-boom clearance.

    ``rig``: a :class:`pipeline.geometry.rig.Rig` (its ``boom_clearance``); ``joints``: per boom a
    ``(H + 1, n)`` tensor of its joint solutions, row H its park (rows of holes it cannot drill are
    never read; NaN is fine); ``limits``: per boom its :class:`JointLimits`."""

    def __init__(self, rig, joints: Sequence[torch.Tensor], limits: Sequence[JointLimits], sample_m: float = 0.01,
                 traj_tol_m: float = 0.001):
        self.rig, self.limits = rig, list(limits)
        self.joints = [torch.as_tensor(q, dtype=D) for q in joints]
        self.levers = [lever_arms(m.boom) for m in rig.booms]
        self.sample_m, self.traj_tol_m = float(sample_m), float(traj_tol_m)
        self.block = 16  # instants per pair and round of the advancement (fewer rounds, bigger batches)
        self.floor = 2 * self.traj_tol_m  # kept between samples: the trajectory file stays clear
        self.margin = self.sample_m / 2 + self.floor
        self._standing: dict[tuple[int, int], np.ndarray] = {}
        self.evaluations = 0  # boom-boom clearance evaluations (pairs of configurations), for reports
        self.detours: list[dict[tuple[int, int], Path]] = [{} for _ in self.joints]
        self._detour_id = [np.full((q.shape[0], q.shape[0]), -1, np.int64) for q in self.joints]
        # certified sweep results of action pairs (pipeline.events.conflicts): key -> (least, lower); an
        # action's sweep is fixed by its boom, kind and nodes (a move's motion never changes once looked at)
        self.sweep_pairs: dict[tuple, tuple[float, float]] = {}
        self._stacked: list[dict | None] = [None for _ in self.joints]
        # the advancement compiled where both booms have a kernel (pipeline.round.compiled_oracle; calibrated too);
        # False keeps it on torch (the reference the kernel is tested against, and the path of a boom without a kernel)
        self.compiled = True

    def set_detour(self, b: int, u: int, v: int, path: Path) -> None:
        """Boom b moves u -> v along ``path`` (it starts at node u's joints up to full turns and ends at
        node v's); the instance's ``move_s[b, u, v]`` must be ``path.duration``."""
        self.detours[b][(u, v)] = path
        if self._detour_id[b][u, v] < 0:
            self._detour_id[b][u, v] = len(self.detours[b]) - 1
        order = sorted(self.detours[b], key=lambda key: self._detour_id[b][key])
        paths = [self.detours[b][key] for key in order]
        span = max(p.duration for p in paths) + 1.0  # detour d's segments live at d * span + their start
        segs = [p.segments for p in paths]
        cat = {f.name: torch.cat([getattr(g, f.name) for g in segs]) for f in dataclasses.fields(Profile)}
        owner = torch.cat([torch.full((g.duration.shape[0],), d, dtype=torch.long) for d, g in enumerate(segs)])
        starts = torch.cat([p.starts + d * span for d, p in enumerate(paths)])
        K = (cat["step"].abs() * self.levers[b]).sum(-1)
        speed = torch.zeros(len(paths), dtype=D).scatter_reduce(0, owner, cat["peak"] * K * (cat["duration"] > 0),
                                                                 "amax")
        self._stacked[b] = {"seg": Profile(**cat), "starts": starts, "span": span, "speed": speed,
                            "duration": torch.tensor([p.duration for p in paths], dtype=D)}

    def detour(self, b: int, u: int, v: int) -> Path | None:
        return self.detours[b].get((u, v))

    def rows(self, b: int, u: int, v: int, q_from: torch.Tensor):
        """Trajectory rows ``(t, q)`` of boom b's move u -> v from ``q_from`` (node u's joints, unwrapped
        as the file runs): linear interpolation within ``traj_tol_m`` of the motion at every point."""
        path = self.detour(b, u, v)
        if path is None:
            return move_rows(q_from, self.joints[b][v], self.limits[b], self.levers[b].numpy(), self.traj_tol_m)
        t, q = path.rows(self.levers[b], self.traj_tol_m)
        turns = torch.round((q_from - q[0]) / (2 * math.pi)) * 2 * math.pi  # full turns only (q4, q7)
        turns = torch.where(torch.tensor(self.limits[b].wrap), turns, torch.zeros_like(turns))
        return t.numpy(), (q + turns).numpy()

    def standing(self, a: int, b: int) -> np.ndarray:
        """``(H + 1, H + 1)`` clearance (m, less d_boom) of boom a at node i and boom b at node j."""
        if (a, b) not in self._standing:
            if (b, a) in self._standing:
                return self._standing[(b, a)].T
            qa, qb = self.joints[a], self.joints[b]
            with torch.inference_mode():
                c = self.rig.boom_clearance(a, qa[:, None, :], b, qb[None, :, :])
            self.evaluations += c.numel()
            self._standing[(a, b)] = c.numpy()
        return self._standing[(a, b)]

    def speed_bound(self, b: int, u: np.ndarray, v: np.ndarray):
        """Per move u -> v of boom b: its motion (a batch for :func:`_positions`) and a bound (m/s) on the
        speed of any point of it (a detour's: the largest over its segments)."""
        q = self.joints[b]
        prof = profile(q[torch.as_tensor(u)], q[torch.as_tensor(v)], self.limits[b])
        K = (prof.step.abs() * self.levers[b]).sum(-1)
        speed = prof.peak * K * (prof.duration > 0)
        d = torch.as_tensor(self._detour_id[b][u, v])
        stacked = self._stacked[b]
        if stacked is not None and bool((d >= 0).any()):
            speed = torch.where(d >= 0, stacked["speed"][d.clamp_min(0)], speed)
        return {"straight": prof, "detour": d, "stacked": stacked}, speed

    def check(self, a: int, seg_a: dict, b: int, seg_b: dict, lo: np.ndarray, hi: np.ndarray):
        """Pairs k of segments (``t0, u, v`` arrays per boom) over ``[lo_k, hi_k]``: the first instant
        of conflict (inf if none) and the smallest sampled clearance (m, less d_boom)."""
        n = len(lo)
        first, least = np.full(n, np.inf), np.full(n, np.inf)
        if n == 0:
            return first, least
        still = (seg_a["u"] == seg_a["v"]) & (seg_b["u"] == seg_b["v"])
        if still.any():
            c = self.standing(a, b)[seg_a["u"][still], seg_b["u"][still]]
            least[still] = c
            first[still] = np.where(c < 0, lo[still], np.inf)
        moving = np.flatnonzero(~still)
        if len(moving) == 0:
            return first, least
        pa, va = self.speed_bound(a, seg_a["u"][moving], seg_a["v"][moving])
        pb, vb = self.speed_bound(b, seg_b["u"][moving], seg_b["v"][moving])
        v = (va + vb).clamp_min(1e-9)
        if self.compiled and self.rig.booms[a].kernel is not None and self.rig.booms[b].kernel is not None:
            first[moving], least[moving] = self._advance_compiled(a, pa, seg_a["t0"][moving], b, pb,
                                                                  seg_b["t0"][moving], lo[moving], hi[moving], v)
            return first, least
        t = torch.as_tensor(lo[moving], dtype=D).clone()
        hi_m = torch.as_tensor(hi[moving], dtype=D)
        ta0 = torch.as_tensor(seg_a["t0"][moving], dtype=D)
        tb0 = torch.as_tensor(seg_b["t0"][moving], dtype=D)
        f = torch.full((len(moving),), math.inf, dtype=D)
        m = torch.full((len(moving),), math.inf, dtype=D)
        active = torch.arange(len(moving))
        step = self.sample_m / 2 / v  # the shortest step above the margin
        M = self.block
        j = torch.arange(M, dtype=D)
        with torch.inference_mode():
            while len(active):  # conservative advancement, all pairs at once, M instants per pair a round
                n_act = len(active)
                T = t[active, None] + step[active, None] * j  # (P, M)
                rep = active.repeat_interleave(M)
                c = self.rig.boom_clearance(a, _positions(pa, rep, T.flatten() - ta0[rep]),
                                            b, _positions(pb, rep, T.flatten() - tb0[rep])).view(n_act, M)
                self.evaluations += c.numel()
                reach = T + (c - self.floor) / v[active, None]  # clear (>= floor) up to there
                bad = c < self.margin
                gap = torch.ones_like(bad)
                gap[:, :-1] = T[:, 1:] > reach[:, :-1]
                stop = bad | gap
                js = stop.to(torch.int8).argmax(1)  # first instant that ends the covered run
                rows = torch.arange(n_act)
                upto = j[None, :] <= js[:, None].to(D)
                m[active] = torch.minimum(m[active], torch.where(upto, c, torch.full_like(c, math.inf)).amin(1))
                hit = bad[rows, js]
                f[active[hit]] = T[rows, js][hit]
                t[active] = reach[rows, js]
                last = c[rows, js]
                step[active] = torch.maximum(self.sample_m / 2 / v[active], (last - self.floor) / v[active])
                active = active[~hit & (t[active] < hi_m[active])]
        first[moving], least[moving] = f.numpy(), m.numpy()
        return first, least

    def _advance_compiled(self, a: int, pa: dict, t0a, b: int, pb: dict, t0b, lo, hi, v: torch.Tensor):
        """:meth:`check`'s advancement of moving pairs in :func:`pipeline.round.compiled_oracle.advance`:
        the same instants and numbers, the booms in the order ``Rig.boom_clearance`` measures them."""
        if a > b:
            a, pa, t0a, b, pb, t0b = b, pb, t0b, a, pa, t0a
        f, m, evaluations = advance(_f64(lo), _f64(hi), _f64(t0a), _f64(t0b), _f64(v), _motion(pa), _motion(pb),
                                    self._kernel_boom(a), self._kernel_boom(b), float(self.rig.d_boom),
                                    self.floor, self.margin, self.sample_m / 2, self.block)
        self.evaluations += evaluations
        return f, m

    def _kernel_boom(self, b: int):
        k = self.rig.booms[b].kernel
        return k.chain, k.base, k.safety.end_frame, k.safety.end_along, k.radius


def _f64(x) -> np.ndarray:
    return np.ascontiguousarray(x.numpy() if isinstance(x, torch.Tensor) else x, dtype=np.float64)


def _motion(motion: dict) -> tuple:
    """A batch of :meth:`KinematicOracle.speed_bound` as the kernel's tuple of arrays."""
    prof, stacked = motion["straight"], motion["stacked"]
    straight = [_f64(getattr(prof, f)) for f in ("start", "step", "duration", "tau", "accel", "peak")]
    detour = np.ascontiguousarray(motion["detour"].numpy(), dtype=np.int64)
    if stacked is None:
        n = straight[0].shape[1]
        segs = [np.empty((0, n)), np.empty((0, n))] + [np.empty(0) for _ in range(5)]
        return (*straight, detour, *segs, 0.0, np.empty(0))
    seg = stacked["seg"]
    segs = [_f64(getattr(seg, f)) for f in ("start", "step", "duration", "tau", "accel", "peak")]
    return (*straight, detour, *segs, _f64(stacked["starts"]), float(stacked["span"]), _f64(stacked["duration"]))


def _positions(motion: dict, pair: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Joints at time ``t`` (from each move's start) of the moves ``pair`` of a batch of
    :meth:`KinematicOracle.speed_bound`: the straight profile, or the detour's segment at that time."""
    q = _profile_at(motion["straight"], pair, t)
    d, stacked = motion["detour"][pair], motion["stacked"]
    if stacked is None or not bool((d >= 0).any()):
        return q
    on = torch.nonzero(d >= 0).squeeze(-1)
    dd = d[on]
    local = torch.minimum(t[on].clamp_min(0), stacked["duration"][dd])
    g = dd.to(D) * stacked["span"] + local  # each detour's segments at d * span + their start: one search
    i = (torch.searchsorted(stacked["starts"], g, right=True) - 1).clamp_min(0)
    q = q.clone()
    q[on] = _profile_at(stacked["seg"], i, g - stacked["starts"][i])
    return q


def _profile_at(prof, pair: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Joints at time ``t`` (from each move's start) of the moves ``pair`` of a batched profile."""
    T, tau, A, V = prof.duration[pair], prof.tau[pair], prof.accel[pair], prof.peak[pair]
    t = torch.minimum(t.clamp_min(0), T)
    rise = 0.5 * A * t * t
    cruise = 0.5 * A * tau * tau + V * (t - tau)
    fall = 1 - 0.5 * A * (T - t) ** 2
    s = torch.where(t < tau, rise, torch.where(t > T - tau, fall, cruise))
    s = torch.where(T > 0, s, torch.ones_like(s))
    return prof.start[pair] + s[:, None] * prof.step[pair]


def move_rows(prof_start: torch.Tensor, prof_end: torch.Tensor, limits: JointLimits, lever: np.ndarray,
              tol_m: float = 0.001):
    """Row instants (s from the move's start) and joints of one move, dense enough that linear
    interpolation in t between rows stays within ``tol_m`` of the planned motion at every point.

    Rows and plan lie on the same joint-space line; between rows at ``h`` apart in an acceleration
    phase the path parameter of the interpolation is off by at most ``A h^2 / 8`` (A the path
    acceleration), so every point by at most ``A h^2 / 8 * K`` with ``K = sum_i |step_i| lever_i``:
    rows ``h <= sqrt(8 tol / (A K))`` apart there; the cruise is linear in t (its two ends suffice)."""
    prof = profile(prof_start, prof_end, limits)
    T, tau, A = float(prof.duration), float(prof.tau), float(prof.accel)
    if T <= 0:
        return np.zeros(1), prof_start[None].numpy()
    K = float((prof.step.abs() * torch.as_tensor(lever, dtype=D)).sum())
    h = math.sqrt(8 * tol_m / max(A * K, 1e-12))
    n = max(1, math.ceil(tau / h))
    ts = np.unique(np.concatenate([np.linspace(0, tau, n + 1), np.linspace(T - tau, T, n + 1)]))
    q = prof.positions(torch.as_tensor(ts, dtype=D)).numpy()
    return ts, q
