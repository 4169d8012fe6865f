"""A rig's clearances as numba kernels: each boom's own four (self, wall, ground, arch, seen from its
base: :meth:`pipeline.geometry.rig.MountedBoom.clearances`) and the boom-boom clearance of two booms
(:meth:`pipeline.geometry.rig.Rig.boom_clearance`), for the round's conflict oracle and its move checks.

Why a second copy: the oracle and the motion planner's validity checks ask for clearances in
thousands of small batches (16 instants per pair of segments and round of the oracle's
advancement; one state, or one edge of a few dozen, per OMPL call), and torch spends its
per-operation overhead on each (the chain alone is about 40 operations). These kernels do the same
arithmetic in one compiled loop: the chain of :func:`~pipeline.geometry.compiled_kinematics.frames_into`,
the base offset added to every origin as :meth:`MountedBoom.to_rig` does, then
:func:`~pipeline.geometry.compiled_kinematics.clearances_into` (the safety model's clearances) or the
clamped segment distance of every capsule pair less both radii and ``d_boom``, in
:class:`~pipeline.geometry.boom_pair.BoomPair`'s order. tests/test_compiled_rig.py holds both equal to
the torch versions at float64 rounding level.

They know the nominal D-H chain and the calibrated one (each link premultiplied by its error transform,
:class:`~pipeline.calibration.error_model.BoomWithErrors`), so a calibrated rig's round and moves run
compiled too; :meth:`CompiledBoom.for_boom` answers ``None`` for a chain of any other kind (its clearances
stay on torch) and checks a calibrated boom's kernel frames against its own before giving it out.

Joints that are not finite (a NaN row of a boom's joint table: a hole it cannot drill) give -inf,
never clear under any comparison: the kernels' minima would skip a NaN, and torch's where-based
arithmetic gives NaN for some kinds and an arbitrary negative value for others.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

from pipeline.core.errors import InputError
from pipeline.geometry.collision import SAFETY_KINDS, SafetyModel
from pipeline.geometry.compiled_kinematics import (
    ChainArrays,
    SafetyArrays,
    _ends,
    chain_and_errors,
    clearances_into,
    frames_into,
    segment_distance,
)
from pipeline.geometry.kinematics import Boom


@njit(cache=True)
def rig_frames_into(q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base, F):
    """:func:`frames_into` (calibrated where ``errors`` has a transform per row), then every origin moved
    by ``base (3,)``: the frames in the rig frame."""
    frames_into(q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, F)
    for f in range(F.shape[0]):
        for i in range(3):
            F[f, i, 3] = F[f, i, 3] + base[i]


@njit(cache=True)
def boom_clearances(Q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base, end_frame,
                    end_along, radius, skip, pairs, d_self, surface, half_width, wall_height, t, exact, outline):
    """The four clearances ``(K, 4)`` (:data:`SAFETY_KINDS` order) of joints ``Q (K, n)`` of a boom
    mounted at ``base``: the safety model on its rig-frame frames."""
    K = Q.shape[0]
    F = np.empty((rows.shape[0] + 2, 4, 4))
    out = np.empty((K, 4))
    arg, frac = np.empty(4, dtype=np.int64), np.empty(4)
    E = np.empty((end_frame.shape[0], 3))
    for k in range(K):
        rig_frames_into(Q[k], rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base, F)
        clearances_into(F, end_frame, end_along, radius, skip, pairs, d_self, surface, half_width, wall_height, t,
                        exact, outline, out[k], arg, frac, E)
    return out


@njit(cache=True)
def capsule_ends(Q, rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base, end_frame,
                 end_along):
    """Capsule axis ends ``(K, 2 * bodies, 3)`` (start, end of each body) of joints ``Q (K, n)`` in the
    rig frame."""
    K = Q.shape[0]
    F = np.empty((rows.shape[0] + 2, 4, 4))
    E = np.empty((K, end_frame.shape[0], 3))
    for k in range(K):
        rig_frames_into(Q[k], rows, cos_alpha, sin_alpha, modified, joint_row, joint_param, tool, errors, base, F)
        _ends(F, end_frame, end_along, E[k])
    return E


PRUNE_SLACK = 1e-9  # m: a capsule pair is skipped only when its bound clears the best by this (rounding)


@njit(cache=True)
def capsule_min(ea, eb, ra, rb, bound):
    """Smallest capsule distance less both radii of one configuration of boom a (ends ``ea``) and one of
    boom b (``eb``); ``bound (A, B)`` is scratch. NaN ends give NaN or a value (as the every-pair minimum,
    which skips NaN); :func:`indexed_clearances` says why pairs are skipped."""
    A, B = ra.shape[0], rb.shape[0]
    bi, bj, low = 0, 0, np.inf
    for i in range(A):
        for j in range(B):
            g = 0.0
            for k in range(3):
                lo_a, hi_a = min(ea[2 * i, k], ea[2 * i + 1, k]), max(ea[2 * i, k], ea[2 * i + 1, k])
                lo_b, hi_b = min(eb[2 * j, k], eb[2 * j + 1, k]), max(eb[2 * j, k], eb[2 * j + 1, k])
                gap = max(lo_b - hi_a, lo_a - hi_b, 0.0)
                g += gap * gap
            v = np.sqrt(g) - ra[i] - rb[j]
            bound[i, j] = v
            if v < low:
                bi, bj, low = i, j, v
    dist, _, _ = segment_distance(ea[2 * bi], ea[2 * bi + 1], eb[2 * bj], eb[2 * bj + 1])
    best = dist - ra[bi] - rb[bj]
    for i in range(A):
        for j in range(B):
            if (i == bi and j == bj) or bound[i, j] >= best + PRUNE_SLACK:
                continue
            dist, _, _ = segment_distance(ea[2 * i], ea[2 * i + 1], eb[2 * j], eb[2 * j + 1])
            c = dist - ra[i] - rb[j]
            if c < best:
                best = c
    return best


@njit(cache=True)
def indexed_clearances(Ea, Eb, ia, ib, ra, rb, d_boom):
    """Clearance ``(P,)`` (smallest capsule distance less both radii, less ``d_boom``) of boom a's
    configuration ``ia[p]`` (ends ``Ea``) against boom b's ``ib[p]`` (ends ``Eb``).

    Most capsule pairs of two booms are far apart, so each pair's exact segment distance is computed
    only where a cheap lower bound could still beat the best so far: two segments are no closer than
    the axis-aligned boxes of their ends (the norm of the per-axis gaps). The pair with the smallest
    bound is measured first; a pair whose bound clears that best by ``PRUNE_SLACK`` cannot be the
    minimum, so skipping it leaves the minimum as every pair gives it, to the last bit
    (tests/test_compiled_rig.py; about half the time of measuring every pair on the round's calls)."""
    P = ia.shape[0]
    out = np.empty(P)
    bound = np.empty((ra.shape[0], rb.shape[0]))
    for p in range(P):
        best = capsule_min(Ea[ia[p]], Eb[ib[p]], ra, rb, bound)
        if best != best:  # NaN ends (joints not finite): as the unpruned minimum, which skips NaN
            best = np.inf
        out[p] = best - d_boom
    return out


def _joints(q: torch.Tensor, n: int, who: str) -> np.ndarray:
    """``q (..., n)`` as a contiguous float64 ``(K, n)`` array."""
    if q.shape[-1:] != (n,):
        raise InputError(f"compiled rig kernels: {who}'s joints have shape {tuple(q.shape)}, expected (..., {n})")
    return np.ascontiguousarray(q.detach().reshape(-1, n).numpy(), dtype=np.float64)


class CompiledBoom:
    """One mounted boom for the kernels: its chain (with a calibrated boom's error transforms), base
    offset, safety model and capsules as arrays."""

    def __init__(self, boom: Boom, base, safety: SafetyModel):
        chain = chain_and_errors(boom)
        if chain is None:
            raise InputError(f"boom '{boom.name}' ({type(boom).__name__}): its frames are neither the D-H chain of "
                             "its rows nor that chain with per-row error transforms, the two the kernels know")
        nominal, errors = chain
        c = ChainArrays.from_boom(nominal)
        self.name, self.n = boom.name, boom.n_joints
        self.chain = (c.rows, c.cos_alpha, c.sin_alpha, c.modified, c.joint_row, c.joint_param, c.tool, errors)
        self.base = np.array(base, dtype=np.float64)
        self.safety = SafetyArrays.from_model(safety)
        self.radius = self.safety.radius  # every body of the boom, as BoomPair's capsules

    @classmethod
    def for_boom(cls, boom: Boom, base, safety: SafetyModel) -> CompiledBoom | None:
        """The kernels' boom, or ``None`` where its chain is not one they compute (the boom's clearances then
        stay on torch). A calibrated boom is recognised by its interface, so its kernel's frames are checked
        against the boom's own (torch) at two configurations before it is given out."""
        if chain_and_errors(boom) is None or chain_and_errors(safety.boom) is None:
            return None
        kernel = cls(boom, base, safety)
        if kernel.chain[-1].shape[0] == 0:
            return kernel
        lo, hi = boom.limits(torch.float64)
        probe = boom.with_locks(torch.stack([lo + 0.3 * (hi - lo), lo + 0.8 * (hi - lo)]))
        F = np.empty((boom.n_rows + 2, 4, 4))
        for q in probe:
            rig_frames_into(q.numpy(), *kernel.chain, np.zeros(3), F)
            if not np.allclose(F, boom.frames(q).numpy(), rtol=0.0, atol=1e-9):
                return None
        return kernel

    def clearances(self, q: torch.Tensor) -> dict[str, torch.Tensor]:
        """:meth:`MountedBoom.clearances` of ``q (..., n)``: each kind ``(...)``."""
        Q = _joints(q, self.n, f"boom '{self.name}'")
        c = boom_clearances(Q, *self.chain, self.base, *self.safety.args())
        c[~np.isfinite(Q).all(1)] = -np.inf  # never clear (module docstring)
        c = torch.from_numpy(c).reshape(*q.shape[:-1], 4)
        return {k: c[..., i] for i, k in enumerate(SAFETY_KINDS)}

    def ends(self, q: np.ndarray) -> np.ndarray:
        return capsule_ends(q, *self.chain, self.base, self.safety.end_frame, self.safety.end_along)


def pair_clearance(a: CompiledBoom, qa: torch.Tensor, b: CompiledBoom, qb: torch.Tensor, d_boom: float
                   ) -> torch.Tensor:
    """Boom-boom clearance ``(...)`` of boom a at ``qa (..., n_a)`` and boom b at ``qb (..., n_b)``,
    their batch shapes broadcast: each distinct configuration's chain once, then every pairing."""
    Qa, Qb = _joints(qa, a.n, "boom a"), _joints(qb, b.n, "boom b")
    Ea, Eb = a.ends(Qa), b.ends(Qb)
    # numpy's broadcasting: a few microseconds, where torch's broadcast_shapes and index tensors cost the
    # oracle's thousands of small calls about half of their time
    shape = np.broadcast_shapes(tuple(qa.shape[:-1]), tuple(qb.shape[:-1]))
    index = [np.broadcast_to(np.arange(len(Q)).reshape(q.shape[:-1]), shape).ravel() for Q, q in ((Qa, qa), (Qb, qb))]
    c = indexed_clearances(Ea, Eb, index[0], index[1], a.radius, b.radius, float(d_boom))
    c[~(np.isfinite(Qa).all(1)[index[0]] & np.isfinite(Qb).all(1)[index[1]])] = -np.inf  # never clear
    return torch.from_numpy(c).reshape(shape)


def kernel_ready(*qs: torch.Tensor) -> bool:
    """Whether joints can take the kernels: float64 on the CPU, no gradient asked for."""
    grad = torch.is_grad_enabled() and any(q.requires_grad for q in qs)
    return not grad and all(q.dtype == torch.float64 and q.device.type == "cpu" for q in qs)
