"""Timed joint paths of one boom: rest-to-rest straight segments, and piecewise-linear rows.

A :class:`Path` is what a move plans: straight lines in joint space between waypoints, each timed
with the synchronised trapezoid of :mod:`pipeline.motion.timing` and starting and ending at rest
(so the boom stops at every waypoint). Waypoints are *unwrapped*: a full-turn joint's step is the
plain difference of consecutive waypoints, never folded, so the timed motion is exactly the straight
edge that was checked; :func:`unwrapped` turns a goal into the short-way target first.

A :class:`Timed` path is the reference's trajectory-file form (section 7): rows ``(t, q)``, the joints
linear in t between rows, the boom standing at its first row before ``t[0]`` and at its last after
``t[-1]``. Another boom's motion is given to the checks in this form.

Point travel. ``lever`` (``pipeline.motion.checks.lever_arms``) bounds, per joint, how far any boom
point moves per unit of that joint, so a joint step ``dq`` moves every point by at most
``sum_i lever_i |dq_i|`` (:func:`travel`). On a segment ``q = start + s step`` that is
``R |ds|`` with ``R = travel(step)``; the check instants and the rows below are spaced with it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from pipeline.core.errors import InputError
from pipeline.motion.timing import JointLimits, Profile, joint_steps, profile


def travel(dq: torch.Tensor, lever: torch.Tensor) -> torch.Tensor:
    """Upper bound (m) of any boom point's displacement over joint steps ``dq (..., n)``."""
    return (dq.abs() * lever).sum(-1)


def unwrapped(qa: torch.Tensor, qb: torch.Tensor, limits: JointLimits) -> torch.Tensor:
    """``qb`` moved by full turns so that the plain difference from ``qa`` is the short way."""
    return qa + joint_steps(qa, qb, limits)


def no_wrap(limits: JointLimits) -> JointLimits:
    """``limits`` with no full-turn joint: steps are taken as given (waypoints already unwrapped)."""
    return dataclasses.replace(limits, wrap=(False,) * len(limits.wrap))


def path_time(p: Profile, s: torch.Tensor) -> torch.Tensor:
    """The inverse of ``p.path``: times ``(...)`` at which a batch of segments ``(...)`` reach ``s (...)``."""
    T, tau, A, V = p.duration, p.tau, p.accel, p.peak
    s_tau = 0.5 * A * tau * tau
    rise = torch.sqrt(2 * s.clamp_min(0) / A)
    fall = T - torch.sqrt(2 * (1 - s).clamp_min(0) / A)
    cruise = tau + (s - s_tau) / V
    t = torch.where(s <= s_tau, rise, torch.where(s >= 1 - s_tau, fall, cruise))
    return torch.where(T > 0, t.clamp(torch.zeros_like(T), T), torch.zeros_like(t))


def _gather(p: Profile, i: torch.Tensor) -> Profile:
    return Profile(*(getattr(p, f.name)[i] for f in dataclasses.fields(Profile)))


@dataclass(frozen=True)
class Path:
    """Rest-to-rest straight segments ``(S,)`` of one boom, back to back from t = 0."""

    segments: Profile  # batched over segments: start (S, n), step (S, n), duration (S,), ...
    starts: torch.Tensor  # (S,) start time of each segment

    @classmethod
    def through(cls, waypoints: torch.Tensor, limits: JointLimits) -> Path:
        """Stop at every waypoint ``(W, n)`` (unwrapped, W >= 2; repeated waypoints are dropped)."""
        if waypoints.ndim != 2 or waypoints.shape[0] < 2:
            raise InputError(f"waypoints: expected (W >= 2, n_joints), got shape {tuple(waypoints.shape)}")
        keep = torch.ones(waypoints.shape[0], dtype=torch.bool)
        keep[1:] = (waypoints[1:] != waypoints[:-1]).any(-1)
        w = waypoints[keep]
        if w.shape[0] == 1:  # no move at all: one empty segment
            w = torch.cat([w, w])
        seg = profile(w[:-1], w[1:], no_wrap(limits))
        starts = torch.cat([torch.zeros(1, dtype=w.dtype), torch.cumsum(seg.duration, 0)[:-1]])
        return cls(seg, starts)

    @property
    def duration(self) -> float:
        return float(self.starts[-1] + self.segments.duration[-1])

    @property
    def waypoints(self) -> torch.Tensor:
        """The stops ``(S + 1, n)``, unwrapped."""
        return torch.cat([self.segments.start, (self.segments.start[-1] + self.segments.step[-1])[None]])

    def positions(self, t: torch.Tensor) -> torch.Tensor:
        """Joints ``(K, n)`` at times ``t (K,)`` (clamped to the path: at rest before and after)."""
        i = (torch.searchsorted(self.starts, t, right=True) - 1).clamp(0, self.starts.shape[0] - 1)
        seg = _gather(self.segments, i)
        s = seg.path((t - self.starts[i]).unsqueeze(-1)).squeeze(-1)
        return seg.start + s.unsqueeze(-1) * seg.step

    def halfway(self, ta: torch.Tensor, tb: torch.Tensor) -> torch.Tensor:
        """Times ``(K,)`` at which the path is halfway *along its line* (in s, not in t) between the
        times ``ta (K,)`` and ``tb (K,)``, each pair within one segment: the split that halves an
        interval's point travel, so a check refined there halves its drift bound."""
        i = (torch.searchsorted(self.starts, 0.5 * (ta + tb), right=True) - 1).clamp(0, self.starts.shape[0] - 1)
        seg = _gather(self.segments, i)
        sa = seg.path((ta - self.starts[i]).unsqueeze(-1)).squeeze(-1)
        sb = seg.path((tb - self.starts[i]).unsqueeze(-1)).squeeze(-1)
        return self.starts[i] + path_time(seg, 0.5 * (sa + sb))

    def check_instants(self, lever: torch.Tensor, resolution: float) -> torch.Tensor:
        """Increasing times ``(K,)`` such that no boom point moves more than ``resolution`` (m) between
        two of them: each segment at ``ceil(R / resolution)`` equal steps of s, ``R`` its travel bound.
        Every segment's start and end are included."""
        seg = self.segments
        n = torch.ceil(travel(seg.step, lever) / resolution).clamp_min(1).long()  # (S,) steps per segment
        which = torch.repeat_interleave(torch.arange(n.shape[0]), n + 1)
        first = torch.cumsum(n + 1, 0) - (n + 1)
        k = torch.arange(which.shape[0]) - first[which]
        s = k.to(seg.duration.dtype) / n[which].to(seg.duration.dtype)
        t = self.starts[which] + path_time(_gather(seg, which), s)
        return distinct(t)  # a segment's end is the next one's start

    def rows(self, lever: torch.Tensor, tolerance: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Trajectory rows ``t (K,)``, ``q (K, n)``: linear interpolation between them stays within
        ``tolerance`` (m) of this path at every boom point.

        Both sides lie on the segment's line ``start + s step``, so a point's deviation is at most
        ``R |s(t) - s_lin(t)|``. s is quadratic with ``|s''| = accel`` in the two ramps and linear while
        cruising; with rows at the ramps' ends, each interval lies in one phase, and the linear
        interpolant of a quadratic over ``h`` is off by at most ``accel h^2 / 8``. So ramps get rows
        every ``h <= sqrt(8 tolerance / (R accel))``, and the cruise needs none inside. Rows never
        exceed a joint speed: a row-to-row speed is a mean of the path's speed."""
        seg = self.segments
        R = travel(seg.step, lever)
        h = torch.sqrt(8 * tolerance / (R * seg.accel).clamp_min(1e-300))
        n = torch.ceil(seg.tau / h).clamp_min(1).long()  # steps per ramp
        which = torch.repeat_interleave(torch.arange(n.shape[0]), n + 1)
        first = torch.cumsum(n + 1, 0) - (n + 1)
        frac = (torch.arange(which.shape[0]) - first[which]).to(R.dtype) / n[which].to(R.dtype)
        tau, T = seg.tau[which], seg.duration[which]
        t0 = self.starts[which]
        rise, fall = t0 + frac * tau, t0 + T - tau + frac * tau
        t = distinct(torch.cat([rise, fall, self.starts, self.starts + seg.duration]))
        return t, self.positions(t)

    def timed(self, lever: torch.Tensor, tolerance: float, t0: float = 0.0) -> Timed:
        t, q = self.rows(lever, tolerance)
        return Timed(t + t0, q)


@dataclass(frozen=True)
class Timed:
    """A boom's piecewise-linear timed path: rows ``t (K,)`` increasing, ``q (K, n)``; standing at the
    first row before ``t[0]`` and at the last one after ``t[-1]``."""

    t: torch.Tensor
    q: torch.Tensor

    def __post_init__(self):
        if self.t.ndim != 1 or self.q.ndim != 2 or self.q.shape[0] != self.t.shape[0] or self.t.shape[0] < 1:
            raise InputError(f"timed path: expected t (K,) and q (K, n), got {tuple(self.t.shape)} and "
                             f"{tuple(self.q.shape)}")
        if bool((self.t[1:] <= self.t[:-1]).any()):
            raise InputError("timed path: times must increase strictly from row to row")

    @classmethod
    def standing(cls, q: torch.Tensor) -> Timed:
        return cls(torch.zeros(1, dtype=q.dtype), q.reshape(1, -1))

    def at(self, t: torch.Tensor) -> torch.Tensor:
        """Joints ``(K, n)`` at times ``t (K,)``."""
        if self.t.shape[0] == 1:
            return self.q.expand(t.shape[0], -1)
        j = (torch.searchsorted(self.t, t, right=True) - 1).clamp(0, self.t.shape[0] - 2)
        t0, t1 = self.t[j], self.t[j + 1]
        a = ((t - t0) / (t1 - t0)).clamp(0, 1).unsqueeze(-1)
        return self.q[j] + a * (self.q[j + 1] - self.q[j])

    def instants(self, lever: torch.Tensor, resolution: float, t0: float, t1: float) -> torch.Tensor:
        """Times in ``[t0, t1]`` such that this boom moves no point more than ``resolution`` (m)
        between two of them (each row interval cut into ``ceil(travel / resolution)`` equal steps,
        exact for linear motion), ``t0`` and ``t1`` included."""
        ends = torch.tensor([t0, t1], dtype=self.t.dtype)
        if self.t.shape[0] == 1:
            return ends
        n = torch.ceil(travel(self.q[1:] - self.q[:-1], lever) / resolution).clamp_min(1).long()
        which = torch.repeat_interleave(torch.arange(n.shape[0]), n)
        first = torch.cumsum(n, 0) - n
        frac = (torch.arange(which.shape[0]) - first[which]).to(self.t.dtype) / n[which].to(self.t.dtype)
        t = torch.cat([self.t[which] + frac * (self.t[which + 1] - self.t[which]), self.t[-1:], ends])
        return distinct(t[(t >= t0) & (t <= t1)])

    def sweep(self, lever: torch.Tensor, step: float, t0: float) -> torch.Tensor:
        """Configurations ``(M, n)`` from ``t0`` to the end, no point moving more than ``step`` (m)
        from one to the next: every configuration the boom takes from ``t0`` on is within
        ``step / 2`` of one of them (point travel), as it stands still after its last row."""
        t_end = max(float(self.t[-1]), t0)
        return self.at(self.instants(lever, step, t0, t_end))


def distinct(t: torch.Tensor, eps: float = 1e-9) -> torch.Tensor:
    """Sorted times with near-duplicates (closer than ``eps`` s, rounding of sums) merged."""
    t = torch.sort(t).values
    keep = torch.ones_like(t, dtype=torch.bool)
    keep[1:] = t[1:] - t[:-1] > eps
    return t[keep]
