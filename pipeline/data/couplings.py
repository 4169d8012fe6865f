"""Joints on linear couplings: paper 000's way to remove the boom's redundancy, as a sampler.

Paper 000's NM adds two equations, theta2 - theta4 = -180 deg and theta5 + theta1 = -90 deg, in its
own joint zeros (its D-H figure did not survive the OCR). They are the parallel-holding pair of a
drilling boom: a feed joint compensates a boom joint, so the feed keeps its direction while the boom
lifts or swings. In jumbo8's joint zeros (docs/reference.md, section 1) that pair reads ``q2 + q5 = 0`` (feed tilt
cancels boom lift) and ``q1 - q6 = 0`` (feed swing cancels boom swing): with them and q4 = q7 = 0 the
feed stays parallel to +x for any lift, swing and extensions, and with either sign flipped it does
not (``tests/test_couplings.py``). The benchmark's ``solvers.nm_coupled`` uses the same rows.

A row is ``{coeffs: {joint: c, ...}, value: v}`` for ``sum_k c_k q_k = v`` in SI units (rad, m),
the format of ``conf/solver_benchmark/default.yaml``. Each row is solved for one joint, its *dependent*
joint: the one of its joints furthest along the chain that no earlier row took (the compensating
feed joint); the others are drawn.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError
from pipeline.data.holes import DTYPE, joint_box


@dataclass(frozen=True)
class Couplings:
    """``A q = b`` over all joints (``A (k, n_joints)``), and the joint each row is solved for."""

    A: torch.Tensor
    b: torch.Tensor
    dependent: tuple[int, ...]

    def residual(self, q: torch.Tensor) -> torch.Tensor:
        return q @ self.A.T.to(q) - self.b.to(q)


def parse_couplings(rows: Sequence[Mapping], joint_names: Sequence[str], where: str = "couplings") -> Couplings:
    """The coupling rows of a config node, checked: known free joints, numbers, and rows that can be
    solved for their dependent joints (an invertible block)."""
    if isinstance(rows, (str, bytes, Mapping)) or not isinstance(rows, Sequence) or not rows:
        raise ConfigError(f"{where} = {rows!r}: expected a non-empty list of {{coeffs: {{joint: c}}, value: v}}")
    names = list(joint_names)
    A = torch.zeros(len(rows), len(names), dtype=DTYPE)
    b = torch.zeros(len(rows), dtype=DTYPE)
    dependent: list[int] = []
    for r, row in enumerate(rows):
        coeffs = row.get("coeffs") if isinstance(row, Mapping) else None
        unknown = set(row) - {"coeffs", "value"} if isinstance(row, Mapping) else set()
        if not isinstance(coeffs, Mapping) or not coeffs or unknown:
            raise ConfigError(f"{where}[{r}] = {row!r}: expected {{coeffs: {{joint: coefficient}}, value: v}}")
        value = row.get("value", 0.0)
        for name, c in coeffs.items():
            if name not in names:
                raise ConfigError(f"{where}[{r}].coeffs: '{name}' is not a joint of {names}")
            if isinstance(c, bool) or not isinstance(c, (int, float)):
                raise ConfigError(f"{where}[{r}].coeffs.{name} = {c!r}: expected a number")
            A[r, names.index(name)] = float(c)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}[{r}].value = {value!r}: expected a number (SI: rad, m)")
        b[r] = float(value)
        free = [i for i in torch.nonzero(A[r]).squeeze(-1).tolist() if i not in dependent]
        if not free:
            raise ConfigError(f"{where}[{r}]: every joint it names is already solved for by an earlier row")
        dependent.append(max(free))  # the joint furthest along the chain: the compensating one
    if abs(float(torch.linalg.det(A[:, dependent]))) < 1e-12:
        raise ConfigError(f"{where}: the rows cannot be solved for joints {[names[i] for i in dependent]}")
    return Couplings(A, b, tuple(dependent))


def sample_coupled_joints(n: int, boom, seed: int, box: Mapping | None, couplings: Couplings,
                          max_batches: int = 100) -> torch.Tensor:
    """``(n, n_joints)`` joints on the couplings: the free joints uniform within ``box``
    (:func:`pipeline.data.holes.joint_box`), each dependent joint solved from its row, and only the
    vectors whose dependent joints also lie within the box kept (rejection, in seeded batches)."""
    if n <= 0:
        raise ConfigError(f"hole count = {n!r}: expected a positive integer")
    lo, hi = joint_box(boom, box)
    dep = list(couplings.dependent)
    free = [i for i in range(boom.n_joints) if i not in dep]
    A_dep_inv = torch.linalg.inv(couplings.A[:, dep])
    gen = torch.Generator().manual_seed(int(seed))
    kept, have, drawn = [], 0, 0
    for _ in range(max_batches):
        m = max(2 * (n - have), 1024)
        q = lo + torch.rand(m, boom.n_joints, generator=gen, dtype=DTYPE) * (hi - lo)
        # A_dep q_dep = b - A_free q_free
        q[:, dep] = (couplings.b - q[:, free] @ couplings.A[:, free].T) @ A_dep_inv.T
        ok = ((q >= lo - 1e-12) & (q <= hi + 1e-12)).all(dim=1)
        kept.append(q[ok])
        have += int(ok.sum())
        drawn += m
        if have >= n:
            return torch.cat(kept)[:n]
    raise ConfigError(f"couplings: only {have} of {drawn} draws keep their dependent joints "
                      f"{[boom.joint_names[i] for i in dep]} within the box; the box and the couplings barely meet")
