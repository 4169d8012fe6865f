"""The hybrid solver with its arithmetic compiled (numba): one hole in well under a millisecond.

The same solver as :class:`~pipeline.solvers.hybrid.HybridSolver`, the same settings, statuses and
answers; only where the time goes changes:

* **the fast path**, for every hole at once (``prange`` over holes): the network's start (for one
  hole, the checkpoint's weights through a compiled MLP; for a batch, the torch network, whose
  matrix products are already as fast as the CPU allows), the target made reachable
  (:meth:`HybridSolver.consistent`), Levenberg-Marquardt on the pose alone, and one clearance check.
  A hole exact and clear by ``margin`` is done there (most holes), with its errors and clearances.
  Where it is not, the cascade's first stage runs in the same kernel (LM with the safety rows from the
  same start, the better answer kept by the hybrid's ranking, :func:`_rank`): a hole ``ok`` after it
  is done too, with no torch bookkeeping, which is what keeps one hole's tail short;
* **every other hole** goes through the hybrid's own cascade (:meth:`HybridSolver.solve`: safety
  rows, perturbed, random and deep starts, the same starts, ranking and statuses), with each
  :meth:`refine` a compiled kernel over holes and their starts instead of torch's batched loop.
  A hole's starts run in lockstep and stop together once one is done, as the torch version's
  ``owner`` rule does.

The kernels mirror the torch code line for line (same damping rule, the same re-measurement of
clearances, the same projection onto the joint ranges); tests/test_compiled.py holds the statuses
equal to the torch hybrid's. Torch stays the solver for training and for GPU batches.
"""

from __future__ import annotations

import math
import os
import time

import numba
import numpy as np
import torch
from numba import njit, prange

from pipeline.core.errors import InputError
from pipeline.geometry.collision import SAFETY_KINDS
from pipeline.geometry.compiled_kinematics import (
    NO_ERRORS,
    ChainArrays,
    SafetyArrays,
    clearance_jacobians_into,
    clearances_into,
    frames_into,
    pose6_jacobian_into,
)
from pipeline.learning.models import ACTIVATIONS, IKNet
from pipeline.solvers.base import HoleTargets, NetworkSolver, Solver, SolveResult, Targets
from pipeline.solvers.hybrid import STATUSES, Candidates, HybridSettings, HybridSolver

if "NUMBA_THREADING_LAYER" not in os.environ:
    # numba's own pool, whose idle threads sleep: its OpenMP layer would be a second OpenMP runtime beside
    # torch's, and the two pools' spinning threads take turns at 2 cores (slower batches, when measured)
    numba.config.THREADING_LAYER = "workqueue"

N_ROWS = 6 + len(SAFETY_KINDS)  # pose rows, then one row per clearance (zero where inactive)
ACTIVATION_CODES = {name: i for i, name in enumerate(sorted(ACTIVATIONS))}  # gelu, relu, silu, tanh


# ---------------------------------------------------------------------------------------------- the network
class CompiledMLP:
    """An :class:`IKNet`'s weights as float32 arrays for :func:`mlp_forward` (the same arithmetic
    as the module: standardise, hidden layers, sigmoid, scale into the joint ranges)."""

    def __init__(self, model: IKNet):
        linears = [m for m in model.net if isinstance(m, torch.nn.Linear)]
        as32 = lambda t: np.ascontiguousarray(t.detach().cpu().float().numpy())  # noqa: E731
        self.W0, self.b0 = as32(linears[0].weight), as32(linears[0].bias)
        hidden = linears[1:-1]
        width = self.W0.shape[0]
        self.Wh = np.stack([as32(m.weight) for m in hidden]) if hidden else np.zeros((0, width, width), np.float32)
        self.bh = np.stack([as32(m.bias) for m in hidden]) if hidden else np.zeros((0, width), np.float32)
        self.Wl, self.bl = as32(linears[-1].weight), as32(linears[-1].bias)
        self.act = ACTIVATION_CODES[model.hparams["activation"]]
        self.mean, self.std = as32(model.in_mean), as32(model.in_std)
        self.lower, self.span = as32(model.lower), as32(model.span)

    def __call__(self, pose: np.ndarray) -> np.ndarray:
        """Joints ``(B, n)`` float64 of poses ``(B, 6)``."""
        return mlp_forward(np.ascontiguousarray(pose, dtype=np.float32), self.W0, self.b0, self.Wh, self.bh, self.Wl,
                           self.bl, self.act, self.mean, self.std, self.lower, self.span)


@njit(cache=True)
def _activate(v, act):
    x = float(v)
    if act == 0:  # gelu (exact, erf)
        return np.float32(0.5 * x * (1.0 + math.erf(x / math.sqrt(2.0))))
    if act == 1:  # relu
        return np.float32(max(x, 0.0))
    if act == 2:  # silu
        return np.float32(x / (1.0 + math.exp(-x)))
    return np.float32(math.tanh(x))


@njit(cache=True, fastmath=True)  # reassociated sums vectorise the dot products (float32 either way)
def _dense(W, b, x, out, act):
    for i in range(W.shape[0]):
        s = np.float32(0.0)
        for j in range(W.shape[1]):
            s += W[i, j] * x[j]
        s += b[i]
        out[i] = _activate(s, act) if act >= 0 else s


@njit(cache=True)
def mlp_forward(pose, W0, b0, Wh, bh, Wl, bl, act, mean, std, lower, span):
    B, width, n = pose.shape[0], W0.shape[0], Wl.shape[0]
    out = np.empty((B, n))
    x = np.empty(pose.shape[1], dtype=np.float32)
    h, g = np.empty(width, dtype=np.float32), np.empty(width, dtype=np.float32)
    z = np.empty(n, dtype=np.float32)
    for b in range(B):
        for i in range(x.shape[0]):
            x[i] = (pose[b, i] - mean[i]) / std[i]
        _dense(W0, b0, x, h, act)
        for k in range(Wh.shape[0]):
            _dense(Wh[k], bh[k], h, g, act)
            h[:] = g
        _dense(Wl, bl, h, z, -1)
        for i in range(n):
            sig = np.float32(1.0 / (1.0 + math.exp(-float(z[i]))))
            out[b, i] = float(lower[i] + span[i] * sig)
    return out


# ---------------------------------------------------------------------------------------------- LM on one hole
# Kernel arguments travel as tuples: ``ch`` the chain (:meth:`ChainArrays.args`), ``sf`` the safety
# model (:meth:`SafetyArrays.args`), ``sp`` the joint space (free indices, full vector of the fixed
# values, lower, upper, wraps) and ``st`` the settings (damping, stop_tol, margin, guard, weight).
@njit(cache=True)
def _project(x, lo, hi, wraps):
    for i in range(x.shape[0]):
        if wraps[i]:  # torch.remainder: the result takes the divisor's sign
            m = np.fmod(x[i] - lo[i], 2 * math.pi)
            if m < 0.0:
                m += 2 * math.pi
            x[i] = m + lo[i]
        else:
            x[i] = min(max(x[i], lo[i]), hi[i])


@njit(cache=True)
def _frames(x, sp, ch, q, F):
    free = sp[0]
    for i in range(free.shape[0]):
        q[free[i]] = x[i]
    frames_into(q, ch[0], ch[1], ch[2], ch[3], ch[4], ch[5], ch[6], NO_ERRORS, F)


@njit(cache=True)
def _clearances(F, ch, sf, c, arg, frac, E):
    clearances_into(F, sf[0], sf[1], sf[2], sf[3], sf[4], sf[5], sf[6], sf[7], sf[8], sf[9], sf[10], sf[11], c, arg,
                    frac, E)


@njit(cache=True)
def _evaluate(x, target, mode, c_prev, sp, ch, sf, st, q, F, pose, Jfull, Gfull, cc, arg, frac, E, r, J, c):
    """The hybrid's ``_rows`` for one start: residual ``r (N_ROWS,)`` (pose rows, then the active
    clearance rows ``w (c - margin)``, zero elsewhere), its Jacobian ``J (N_ROWS, n_free)`` and the
    clearances ``c (4,)``. ``mode`` 0: pose only (clearances NaN, not measured); 1: clearances
    re-measured only where ``c_prev``'s smallest is below ``guard``. Returns (hole error, measured)."""
    free = sp[0]
    nf = free.shape[0]
    margin, guard, weight = st[2], st[3], st[4]
    _frames(x, sp, ch, q, F)
    pose6_jacobian_into(F, ch[11], ch[7], ch[8], ch[9], pose, Jfull)
    for i in range(6):
        r[i] = pose[i] - target[i]
        for j in range(nf):
            J[i, j] = Jfull[i, free[j]]
    hole = 0.5 * (math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                  + math.sqrt(r[3] * r[3] + r[4] * r[4] + r[5] * r[5]))
    for k in range(4):
        r[6 + k] = 0.0
        for j in range(nf):
            J[6 + k, j] = 0.0
    if mode == 0:
        for k in range(4):
            c[k] = np.nan
        return hole, False
    fresh = min(min(c_prev[0], c_prev[1]), min(c_prev[2], c_prev[3])) < guard
    for k in range(4):
        c[k] = c_prev[k]
    if fresh:
        _clearances(F, ch, sf, c, arg, frac, E)
    any_active = False
    for k in range(4):
        any_active = any_active or c[k] < margin
    if any_active:
        clearance_jacobians_into(F, sf[0], sf[1], sf[2], sf[3], sf[4], sf[5], sf[6], sf[7], sf[8], sf[9], sf[10],
                                 sf[11], ch[7], ch[8], ch[9], ch[10], cc, Gfull)
        for k in range(4):
            if c[k] < margin:
                r[6 + k] = weight * (c[k] - margin)
                for j in range(nf):
                    J[6 + k, j] = weight * Gfull[k, free[j]]
    return hole, fresh


@njit(cache=True)
def _solve_into(A, b, s):
    """``s = A^-1 b`` by Gaussian elimination with partial pivoting (A is overwritten)."""
    n = b.shape[0]
    for i in range(n):
        s[i] = b[i]
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(A[i, k]) > abs(A[p, k]):
                p = i
        if p != k:
            for j in range(n):
                A[k, j], A[p, j] = A[p, j], A[k, j]
            s[k], s[p] = s[p], s[k]
        for i in range(k + 1, n):
            f = A[i, k] / A[k, k]
            for j in range(k, n):
                A[i, j] -= f * A[k, j]
            s[i] -= f * s[k]
    for k in range(n - 1, -1, -1):
        v = s[k]
        for j in range(k + 1, n):
            v -= A[k, j] * s[j]
        s[k] = v / A[k, k]


@njit(cache=True)
def _sq(v):
    s = 0.0
    for i in range(v.shape[0]):
        s += v[i] * v[i]
    return s


@njit(cache=True)
def refine_hole(X0, target, use_safety, max_iters, sp, ch, sf, st, X, R6, C, iters):
    """The hybrid's :meth:`refine` for the ``K`` starts ``X0 (K, n_free)`` of one hole: each start
    runs LM until exact (and, with ``use_safety``, clear); once one start is done, the hole's other
    starts stop where they are. Writes the joints ``X``, pose residuals ``R6``, clearances ``C``
    (always measured at ``X``) and iteration counts ``iters``. One workspace allocation per call."""
    free, fixed, lo, hi, wraps = sp
    damping, stop_tol = st[0], st[1]
    K, nf, n, nF, nE = X0.shape[0], free.shape[0], fixed.shape[0], ch[0].shape[0] + 2, sf[0].shape[0]
    mode = 1 if use_safety else 0
    sizes = (n, nF * 16, 6, 6 * n, 4 * n, 4, 4, 3 * nE, K * N_ROWS, K * N_ROWS * nf, K * 4, K, K, K,
             N_ROWS, N_ROWS * nf, 4, nf, nf * nf, nf, nf, 4)
    total = 0
    for v in sizes:
        total += v
    w = np.empty(total)
    o = 0
    q = w[o:o + n]
    o += n
    F = w[o:o + nF * 16].reshape((nF, 4, 4))
    o += nF * 16
    pose = w[o:o + 6]
    o += 6
    Jfull = w[o:o + 6 * n].reshape((6, n))
    o += 6 * n
    Gfull = w[o:o + 4 * n].reshape((4, n))
    o += 4 * n
    cc = w[o:o + 4]
    o += 4
    frac = w[o:o + 4]
    o += 4
    E = w[o:o + 3 * nE].reshape((nE, 3))
    o += 3 * nE
    r = w[o:o + K * N_ROWS].reshape((K, N_ROWS))
    o += K * N_ROWS
    J = w[o:o + K * N_ROWS * nf].reshape((K, N_ROWS, nf))
    o += K * N_ROWS * nf
    c = w[o:o + K * 4].reshape((K, 4))
    o += K * 4
    hole = w[o:o + K]
    o += K
    cost = w[o:o + K]
    o += K
    lam = w[o:o + K]
    o += K
    rn = w[o:o + N_ROWS]
    o += N_ROWS
    Jn = w[o:o + N_ROWS * nf].reshape((N_ROWS, nf))
    o += N_ROWS * nf
    cn = w[o:o + 4]
    o += 4
    xn = w[o:o + nf]
    o += nf
    A = w[o:o + nf * nf].reshape((nf, nf))
    o += nf * nf
    g = w[o:o + nf]
    o += nf
    step = w[o:o + nf]
    o += nf
    minus_inf = w[o:o + 4]
    minus_inf[:] = -np.inf
    q[:] = fixed
    arg = np.empty(4, dtype=np.int64)
    fresh = np.zeros(K, dtype=np.bool_)
    for k in range(K):
        X[k] = X0[k]
        _project(X[k], lo, hi, wraps)
        hole[k], fresh[k] = _evaluate(X[k], target, mode, minus_inf, sp, ch, sf, st, q, F, pose, Jfull, Gfull, cc,
                                      arg, frac, E, r[k], J[k], c[k])
        cost[k] = _sq(r[k])
        lam[k] = damping
        iters[k] = 0
    for it in range(max_iters + 1):
        any_done = False
        for k in range(K):
            done = hole[k] <= stop_tol and (not use_safety or c[k].min() >= 0)
            if use_safety and done and not fresh[k]:  # exact on clearances measured earlier: measure them here
                hole[k], fresh[k] = _evaluate(X[k], target, mode, minus_inf, sp, ch, sf, st, q, F, pose, Jfull,
                                              Gfull, cc, arg, frac, E, r[k], J[k], c[k])
                cost[k] = _sq(r[k])
                done = hole[k] <= stop_tol and c[k].min() >= 0
            any_done = any_done or done
        if any_done or it == max_iters:
            break
        for k in range(K):
            Jk, rk = J[k], r[k]
            for i in range(nf):
                for j in range(i, nf):
                    s = 0.0
                    for m in range(N_ROWS):
                        s += Jk[m, i] * Jk[m, j]
                    A[i, j] = s
                    A[j, i] = s
                s = 0.0
                for m in range(N_ROWS):
                    s += Jk[m, i] * rk[m]
                g[i] = -s
            for i in range(nf):  # Marquardt scaling, as the torch hybrid
                A[i, i] += lam[k] * (A[i, i] + 1e-9)
            _solve_into(A, g, step)
            for i in range(nf):
                xn[i] = X[k, i] + step[i]
            _project(xn, lo, hi, wraps)
            hn, fn = _evaluate(xn, target, mode, c[k], sp, ch, sf, st, q, F, pose, Jfull, Gfull, cc, arg, frac, E,
                               rn, Jn, cn)
            cost_new = _sq(rn)
            if cost_new < cost[k]:
                X[k] = xn
                r[k] = rn
                J[k] = Jn
                c[k] = cn
                hole[k], fresh[k], cost[k] = hn, fn, cost_new
                lam[k] = max(lam[k] * 0.3, 1e-12)
            else:
                lam[k] = min(lam[k] * 10.0, 1e8)
            iters[k] += 1
    for k in range(K):
        for i in range(6):
            R6[k, i] = r[k, i]
        C[k] = c[k]
        if not fresh[k]:  # the answer's own clearances, wherever the loop reused older ones
            _frames(X[k], sp, ch, q, F)
            _clearances(F, ch, sf, C[k], arg, frac, E)


@njit(cache=True, parallel=True)
def refine_holes(X0, targets, use_safety, max_iters, sp, ch, sf, st):
    """:func:`refine_hole` for ``H`` holes of ``K`` starts each, ``X0 (H, K, n_free)``, in parallel."""
    H, K, nf = X0.shape
    X, R6, C = np.empty((H, K, nf)), np.empty((H, K, 6)), np.empty((H, K, 4))
    iters = np.empty((H, K), dtype=np.int64)
    for h in prange(H):
        refine_hole(X0[h], targets[h], use_safety, max_iters, sp, ch, sf, st, X[h], R6[h], C[h], iters[h])
    return X, R6, C, iters


# ---------------------------------------------------------------------------------------------- the fast path
@njit(cache=True)
def _rank(hole, C, X, X_ref, lo, hi, tol, reach, prefer_start):
    """:meth:`HybridSolver.rank` of one candidate: (status index, score to minimise)."""
    worst = min(min(C[0], C[1]), min(C[2], C[3]))
    exact, clear, reached = hole <= tol, worst >= 0, hole <= reach
    status = 3
    if reached and not clear:
        status = 2
    if clear and reached:
        status = 1
    if exact and clear:
        status = 0
    w = min(max(worst, -10.0), 10.0)
    key = -w if status == 0 else min(hole, 1e3)
    if status == 2:
        key = -w + (0.0 if exact else 100.0)
    if prefer_start and status == 0:
        key = 0.0
        for i in range(X.shape[0]):
            d = (X[i] - X_ref[i]) / (hi[i] - lo[i])
            key += d * d
    return status, status * 1e6 + key


@njit(cache=True)
def _errors_into(pose, target, R6, E):
    """Start, preview and hole-seeking error and the direction error (rad) of the reached pose
    ``target + R6`` against the pose as given (:func:`~pipeline.geometry.kinematics.pose_errors`)."""
    e_s, e_p, uv = 0.0, 0.0, 0.0
    u, v = np.empty(3), np.empty(3)
    for i in range(3):
        e_s += (target[i] + R6[i] - pose[i]) ** 2
        e_p += (target[3 + i] + R6[3 + i] - pose[3 + i]) ** 2
        u[i] = (target[3 + i] + R6[3 + i]) - (target[i] + R6[i])
        v[i] = pose[3 + i] - pose[i]
        uv += u[i] * v[i]
    cx, cy, cz = u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
    e_s, e_p = math.sqrt(e_s), math.sqrt(e_p)
    E[0], E[1], E[2] = e_s, e_p, 0.5 * (e_s + e_p)
    E[3] = math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), uv)


@njit(cache=True)
def _fast_hole(pose, q0, max_iters, tol, sp, ch, sf, st, Q, E, C, iters):
    """One hole's fast path: reachable target, pose-only LM from ``q0``; where that answer is not exact
    and clear by ``margin``, the cascade's first stage too (LM with the safety rows from ``q0``, the
    better of the two answers kept by the hybrid's ranking). Writes the joints ``Q``, errors ``E``
    (start, preview, hole, direction; against the pose as given), clearances ``C`` and iterations (both
    stages' summed, as the hybrid counts them). Returns whether the hole is done, as
    :meth:`HybridSolver.solve` decides: the pose-only answer exact and clear by at least ``margin``, or the
    answer kept after the first stage ``ok``. The others go through the hybrid's whole cascade."""
    free, fixed, lo, hi = sp[0], sp[1], sp[2], sp[3]
    depth, margin, reach, prefer_start = ch[11], st[2], st[5], st[6] > 0
    nf = free.shape[0]
    target = np.empty(6)
    a0, a1, a2 = pose[3] - pose[0], pose[4] - pose[1], pose[5] - pose[2]
    length = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    den = max(length, 1e-12)
    for i in range(3):  # HybridSolver.consistent: the preview point at exactly the preview depth
        target[i] = pose[i]
        target[3 + i] = pose[i] + depth * (pose[3 + i] - pose[i]) / den if length > 1e-9 else pose[3 + i]
    X0 = np.empty((1, nf))
    for i in range(nf):
        X0[0, i] = q0[free[i]]
    X, R6 = np.empty((1, nf)), np.empty((1, 6))
    refine_hole(X0, target, False, max_iters, sp, ch, sf, st, X, R6, C.reshape((1, 4)), iters)
    hole_error = 0.5 * (math.sqrt(_sq(R6[0, :3])) + math.sqrt(_sq(R6[0, 3:])))
    worst = min(min(C[0], C[1]), min(C[2], C[3]))
    done = hole_error <= tol and worst >= margin and worst >= 0
    if not done:  # the cascade's first stage, here: most of the holes the pose-only LM leaves end in it
        X1, R61, C1 = np.empty((1, nf)), np.empty((1, 6)), np.empty((1, 4))
        it1 = np.empty(1, dtype=np.int64)
        refine_hole(X0, target, True, max_iters, sp, ch, sf, st, X1, R61, C1, it1)
        hole1 = 0.5 * (math.sqrt(_sq(R61[0, :3])) + math.sqrt(_sq(R61[0, 3:])))
        status0, score0 = _rank(hole_error, C, X[0], X0[0], lo, hi, tol, reach, prefer_start)
        status1, score1 = _rank(hole1, C1[0], X1[0], X0[0], lo, hi, tol, reach, prefer_start)
        iters[0] += it1[0]
        if score1 < score0:  # the first of equals stays, as the hybrid's argmin keeps it
            status0 = status1
            X[0, :] = X1[0, :]
            R6[0, :] = R61[0, :]
            C[:] = C1[0, :]
        done = status0 == 0
    Q[:] = fixed
    for i in range(nf):
        Q[free[i]] = X[0, i]
    _errors_into(pose, target, R6[0], E)
    return done


@njit(cache=True)
def fast_path(poses, Q0, max_iters, tol, sp, ch, sf, st):
    """:func:`_fast_hole` for every hole, one after another (one hole, or one thread)."""
    B, n = Q0.shape
    Q, E, C = np.empty((B, n)), np.empty((B, 4)), np.empty((B, 4))
    iters, done = np.empty(B, dtype=np.int64), np.empty(B, dtype=np.bool_)
    for b in range(B):
        done[b] = _fast_hole(poses[b], Q0[b], max_iters, tol, sp, ch, sf, st, Q[b], E[b], C[b], iters[b:b + 1])
    return Q, E, C, iters, done


@njit(cache=True, parallel=True)
def fast_path_parallel(poses, Q0, max_iters, tol, sp, ch, sf, st):
    """:func:`fast_path` over numba's threads (a batch)."""
    B, n = Q0.shape
    Q, E, C = np.empty((B, n)), np.empty((B, 4)), np.empty((B, 4))
    iters, done = np.empty(B, dtype=np.int64), np.empty(B, dtype=np.bool_)
    for b in prange(B):
        done[b] = _fast_hole(poses[b], Q0[b], max_iters, tol, sp, ch, sf, st, Q[b], E[b], C[b], iters[b:b + 1])
    return Q, E, C, iters, done


# ---------------------------------------------------------------------------------------------- the solver
class _Given(Solver):
    """The starts already computed, as the cascade's ``init`` (row ``i`` for hole ``i``)."""

    name = "given"

    def __init__(self, boom, q: torch.Tensor):
        super().__init__(boom)
        self.q = q

    def _solve(self, targets):
        if len(targets) != len(self.q):
            raise InputError(f"{self.name}: {len(self.q)} starts for {len(targets)} holes")
        return self.q, torch.ones(len(targets), dtype=torch.long)


class CompiledHybridSolver(HybridSolver):
    """:class:`HybridSolver` with the fast path and every refinement compiled (module docstring).

    ``parallel_from``: batches of at least this many holes use numba's threads (``prange``); smaller
    ones run on the calling thread, with no pool to wake. ``network_from``: batches of at least this
    many holes take their start from the torch network (fast matrix products), smaller ones from the
    compiled MLP (no framework overhead)."""

    name = "hybrid_compiled"

    def __init__(self, boom, safety, init, settings: HybridSettings | None = None, name: str = "hybrid_compiled",
                 start_box=None, parallel_from: int = 64, network_from: int = 16):
        super().__init__(boom, safety, init, settings or HybridSettings(), name, start_box)
        self.chain, self.arrays = ChainArrays.from_boom(boom), SafetyArrays.from_model(safety)
        self.free = np.array(self.space.free, dtype=np.int64)
        self.fixed = self.space.fixed.double().numpy().copy()
        self.lo, self.hi = self.space.lower.double().numpy().copy(), self.space.upper.double().numpy().copy()
        self.wrap_mask = self.wraps.numpy().copy()
        self.parallel_from, self.network_from = parallel_from, network_from
        model = init.model if isinstance(init, NetworkSolver) else None
        self.mlp = CompiledMLP(model) if isinstance(model, IKNet) else None
        self.warm_up()

    def warm_up(self) -> None:
        """Load (or, the first time on a machine, compile: about a minute) every kernel now, so that
        no solve pays for it: two holes through each kernel and mode, at the home pose."""
        home = self.space.full((0.5 * (self.space.lower + self.space.upper))[None]).double()
        pose = self.boom.pose6(home).expand(2, -1).contiguous()
        q0 = home.expand(2, -1).numpy().copy()
        s = self.s
        for kernel in (fast_path, fast_path_parallel):
            kernel(pose.numpy().copy(), q0, 1, s.tol_mm / 1000, *self._kernel_args())
        for use_safety in (False, True):
            self.refine(home.expand(2, -1), pose, use_safety, max_iters=1, owner=torch.tensor([0, 0]))
        if self.mlp is not None:
            self.mlp(pose.numpy())

    def _kernel_args(self) -> tuple:
        """The kernels' tuples: joint space, chain, safety model, settings (see the kernels' comment)."""
        s = self.s
        return ((self.free, self.fixed, self.lo, self.hi, self.wrap_mask), self.chain.args(), self.arrays.args(),
                (float(s.damping), 1e-2 * s.tol_mm / 1000, float(s.margin), float(s.guard),
                 float(s.clearance_weight), s.reach_tol_mm / 1000, float(s.prefer == "start")))

    def refine(self, q0: torch.Tensor, target: torch.Tensor, use_safety: bool,
               max_iters: int | None = None, owner: torch.Tensor | None = None, others=()) -> Candidates:
        """:meth:`HybridSolver.refine` through :func:`refine_holes`. ``owner`` must list each hole's
        starts together, in equal numbers (as :meth:`HybridSolver._try` lays them out). The kernels know
        one boom in its own frame: other booms as obstacles take the torch refinement."""
        if len(others):
            return HybridSolver.refine(self, q0, target, use_safety, max_iters, owner, others)
        max_iters = self.s.max_iters if max_iters is None else max_iters
        N = len(q0)
        if owner is None:
            H, K = N, 1
        else:
            H = int(owner.max()) + 1 if N else 0
            K = N // max(H, 1)
            if H * K != N or not torch.equal(owner, torch.arange(H).repeat_interleave(K)):
                raise InputError(f"{self.name}: refine needs each hole's starts together, equally many")
        x0 = np.ascontiguousarray(q0[:, self.space.free].double().numpy().reshape(H, K, -1))
        tgt = np.ascontiguousarray(target.double().numpy()[::K])
        X, R6, C, iters = refine_holes(x0, tgt, use_safety, max_iters, *self._kernel_args())
        x = torch.from_numpy(X.reshape(N, -1))
        r = torch.from_numpy(R6.reshape(N, 6))
        hole = 0.5 * (r[:, :3].norm(dim=-1) + r[:, 3:].norm(dim=-1))
        return Candidates(self.space.full(x), hole, torch.from_numpy(C.reshape(N, 4)),
                          torch.from_numpy(iters.reshape(N)), r)

    def start_joints(self, targets: HoleTargets, pose: np.ndarray) -> np.ndarray:
        """The network's (or the home pose's) joints ``(B, n_joints)`` for the fast path."""
        if self.init is None:
            home = self.space.full((0.5 * (self.space.lower + self.space.upper))[None])[0].numpy()
            return np.repeat(home[None], len(pose), axis=0)
        if self.mlp is not None and len(pose) < self.network_from:
            return self.mlp(pose)
        return np.ascontiguousarray(self.init.joints(targets).numpy())

    def _cascade(self, targets: HoleTargets, q0: torch.Tensor) -> SolveResult:
        """:meth:`HybridSolver.solve` from the starts the fast path had (no second network pass), its
        torch bookkeeping on one thread: small tensors gain nothing from more, and idle torch threads
        spinning beside numba's would take the cores from the kernels."""
        init, threads = self.init, torch.get_num_threads()
        self.init = _Given(self.boom, q0)
        torch.set_num_threads(1)
        try:
            return HybridSolver.solve(self, targets)
        finally:
            self.init = init
            torch.set_num_threads(threads)

    def solve(self, targets: Targets, obstacles=(), start: torch.Tensor | None = None) -> SolveResult:
        """The fast path for every hole; the hybrid's cascade (compiled refinements) for the rest. With
        other booms as obstacles, or given starts, it is the torch hybrid (its kernels know neither)."""
        if len(obstacles) or start is not None:
            return HybridSolver.solve(self, targets, obstacles, start)
        if not isinstance(targets, HoleTargets):
            raise InputError(f"{self.name}: solves holes (HoleTargets), got {type(targets).__name__}")
        if len(targets) == 0:
            raise InputError(f"{self.name}: no targets to solve")
        start = time.perf_counter()
        pose = targets.pose.detach().cpu().double().numpy()
        q0 = self.start_joints(targets, pose)
        kernel = fast_path_parallel if len(pose) >= self.parallel_from else fast_path
        s = self.s
        Q, E, C, iters, done = kernel(pose, q0, s.max_iters, s.tol_mm / 1000, *self._kernel_args())
        status = np.zeros(len(pose), dtype=np.int64)
        rest = np.flatnonzero(~done)
        q, C_t, it = torch.from_numpy(Q), torch.from_numpy(C), torch.from_numpy(iters)
        errors = {k: torch.from_numpy(np.ascontiguousarray(E[:, i]))
                  for i, k in enumerate(("position", "preview", "hole", "orientation"))}
        if len(rest):  # the hybrid's own cascade, with compiled refinements, for the holes left
            index = torch.from_numpy(rest)
            sub = self._cascade(targets.subset(index), torch.from_numpy(q0[rest]))
            q[index], C_t[index], it[index] = sub.q, torch.stack([sub.clearances[k] for k in SAFETY_KINDS], -1), \
                sub.iterations
            for k in errors:
                errors[k][index] = sub.errors[k]
            status[rest] = [STATUSES.index(v) for v in sub.status]
        wall = time.perf_counter() - start
        errors = {k: errors[k] for k in ("position", "orientation", "preview", "hole")}
        return SolveResult(q, errors, it, wall, status=[STATUSES[i] for i in status.tolist()],
                           clearances={k: C_t[:, i] for i, k in enumerate(SAFETY_KINDS)})
