"""The conflict oracle's conservative advancement as one numba kernel.

:meth:`pipeline.round.oracle.KinematicOracle.check` advances all pairs of segments in lockstep with
torch: a round is about twenty operations on small tensors, and a small round of the test face asks
for tens of thousands of rounds, so torch's per-operation overhead was half of the planner's time.
This kernel runs the same advancement pair after pair (pairs are independent: each pair's instants
depend on its own clearances only), with each instant's joints (:func:`path_at`, the formula of
:meth:`pipeline.motion.timing.Profile.path`), the chain and capsule ends
(:func:`pipeline.geometry.compiled_rig.rig_frames_into`) and the boom-boom clearance
(:func:`pipeline.geometry.compiled_rig.capsule_min`) in one compiled loop. Every operation is the
torch version's, in its order, so both give the same instants and the same numbers to the last bit
(tests/test_detours.py holds them equal, on the nominal and a calibrated rig); the torch version
stays as that reference, and for a boom whose chain the kernels do not know
(:meth:`pipeline.geometry.compiled_rig.CompiledBoom.for_boom` answers ``None``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from pipeline.geometry.compiled_kinematics import _ends
from pipeline.geometry.compiled_rig import capsule_min, rig_frames_into


@njit(cache=True)
def path_at(T, tau, A, V, t):
    """``s(t)`` of one synchronised move (:meth:`pipeline.motion.timing.Profile.path`), t clamped to [0, T]."""
    t = min(max(t, 0.0), T)
    if not T > 0:
        return 1.0  # no move: already at B
    if t < tau:
        return 0.5 * A * t * t
    if t > T - tau:
        x = T - t
        return 1 - 0.5 * A * (x * x)
    return 0.5 * A * tau * tau + V * (t - tau)


@njit(cache=True)
def _joints_at(motion, p, t, q):
    """Joints ``q (n,)`` of move p of ``motion`` at ``t`` s from its start: its straight profile, or its
    detour's segment at that time (``oracle._positions``)."""
    start, step, T, tau, A, V, detour, s_start, s_step, s_T, s_tau, s_A, s_V, s_at, span, s_duration = motion
    d = detour[p]
    if d < 0:
        s = path_at(T[p], tau[p], A[p], V[p], t)
        for i in range(q.shape[0]):
            q[i] = start[p, i] + s * step[p, i]
        return
    g = d * span + min(max(t, 0.0), s_duration[d])  # each detour's segments at d * span + their start
    k = max(np.searchsorted(s_at, g, side="right") - 1, 0)
    s = path_at(s_T[k], s_tau[k], s_A[k], s_V[k], g - s_at[k])
    for i in range(q.shape[0]):
        q[i] = s_start[k, i] + s * s_step[k, i]


@njit(cache=True)
def _clearance(qa, qb, chain_a, base_a, frame_a, along_a, ra, chain_b, base_b, frame_b, along_b, rb, d_boom,
               Fa, Fb, Ea, Eb, bound):
    """Boom-boom clearance of one configuration pair (``pair_clearance``): -inf if a joint is not finite."""
    for i in range(qa.shape[0]):
        if not np.isfinite(qa[i]):
            return -np.inf
    for i in range(qb.shape[0]):
        if not np.isfinite(qb[i]):
            return -np.inf
    rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors = chain_a
    rig_frames_into(qa, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base_a, Fa)
    _ends(Fa, frame_a, along_a, Ea)
    rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors = chain_b
    rig_frames_into(qb, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base_b, Fb)
    _ends(Fb, frame_b, along_b, Eb)
    best = capsule_min(Ea, Eb, ra, rb, bound)
    if best != best:
        best = np.inf
    return best - d_boom


@njit(cache=True)
def advance(lo, hi, t0a, t0b, v, motion_a, motion_b, boom_a, boom_b, d_boom, floor, margin, half, block):
    """First instant of conflict (inf if none) and least clearance sampled, per pair of moving segments,
    by :meth:`KinematicOracle.check`'s advancement; also the number of clearances evaluated.

    ``lo, hi, t0a, t0b, v (P,)``: each pair's interval, its segments' starts and the bound on their
    summed speed; ``motion_*``: the moves (straight profiles and detours, see :func:`_joints_at`);
    ``boom_*``: ``(chain, base, end_frame, end_along, radius)``; ``half``: ``sample_m / 2``."""
    chain_a, base_a, frame_a, along_a, ra = boom_a
    chain_b, base_b, frame_b, along_b, rb = boom_b
    P = lo.shape[0]
    first, least = np.full(P, np.inf), np.full(P, np.inf)
    qa, qb = np.empty(motion_a[0].shape[1]), np.empty(motion_b[0].shape[1])
    Fa, Fb = np.empty((chain_a[0].shape[0] + 2, 4, 4)), np.empty((chain_b[0].shape[0] + 2, 4, 4))
    Ea, Eb = np.empty((frame_a.shape[0], 3)), np.empty((frame_b.shape[0], 3))
    bound = np.empty((ra.shape[0], rb.shape[0]))
    T, c, reach = np.empty(block), np.empty(block), np.empty(block)
    evaluations = 0
    for p in range(P):
        t, step, m = lo[p], half / v[p], np.inf
        while True:
            for j in range(block):
                T[j] = t + step * j
                _joints_at(motion_a, p, T[j] - t0a[p], qa)
                _joints_at(motion_b, p, T[j] - t0b[p], qb)
                c[j] = _clearance(qa, qb, chain_a, base_a, frame_a, along_a, ra, chain_b, base_b, frame_b, along_b,
                                  rb, d_boom, Fa, Fb, Ea, Eb, bound)
                reach[j] = T[j] + (c[j] - floor) / v[p]
            evaluations += block
            js = block - 1  # the first instant that ends the covered run: a conflict, or a gap after it
            for j in range(block - 1):
                if c[j] < margin or T[j + 1] > reach[j]:
                    js = j
                    break
            for j in range(js + 1):
                m = min(m, c[j])
            hit = c[js] < margin
            if hit:
                first[p] = T[js]
            t = reach[js]
            step = max(half / v[p], (c[js] - floor) / v[p])
            if hit or not t < hi[p]:
                break
        least[p] = m
    return first, least, evaluations
