"""Identification of the error twists from measurements (beyond paper 004: the standard in robot
calibration): weighted Levenberg-Marquardt on the measured collar points and drilling directions.

Not every one of the 6 x n_rows twist components changes what a total station sees. Some are the
same motion as another (a turn of the boom-extension tube about its own axis is a turn of the
next, collinear, rotation joint), and a turn of the tool about the drill axis moves neither the
collar nor the direction. :func:`identifiable_basis` finds them from the SVD / Gram-Schmidt of the
identification Jacobian at generic joint vectors, keeps an identifiable basis and reports how
each dropped component is merged into the kept ones. The kept set is chosen greedily in a fixed
preference order, so that the most physical parameters survive:

1. joint-variable errors (a revolute joint's ``rz``, its zero offset; a prismatic joint's ``tz``);
2. axis tilts ``rx, ry``;
3. axis offsets ``tx, ty``;
4. the rest (a revolute joint's ``tz``, a prismatic joint's ``rz``),

each from the base to the tip. :func:`identify` then checks that the measurements at hand
separate that basis (rank and condition number of the Jacobian at their joint vectors) and
raises :class:`InputError` naming the problem when they do not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch.func import jacfwd

from pipeline.calibration.error_model import COMPONENTS, DTYPE, axis_frames, check_supported, parameter_names
from pipeline.calibration.error_model import error_transforms as twist_transforms
from pipeline.calibration.measurements import Measurements
from pipeline.core.errors import ConfigError, Diverged, InputError
from pipeline.geometry.kinematics import Boom
from pipeline.optim.least_squares import Damping, Evaluation, least_squares

EQUATIONS_PER_MEASUREMENT = 5  # collar (3) + direction (2: a unit vector)


@dataclass(frozen=True)
class Weights:
    """Residual scales: what one sensor standard deviation is worth (collar mm, direction deg)."""

    position_mm: float = 1.0
    direction_deg: float = 0.05

    def __post_init__(self):
        for key in ("position_mm", "direction_deg"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"calibration.identification.weights.{key} = {v!r}: expected a number > 0")


@dataclass
class Basis:
    """An identifiable set of twist components and how the others merge into it."""

    names: list[str]  # every component, ``<joint>.<component>``
    kept: list[int]  # indices into ``names``
    merged: dict[str, list[tuple[str, float]]]  # dropped name -> [(kept name, coefficient)]
    condition: float  # of the column-normalised Jacobian restricted to ``kept``

    @property
    def kept_names(self) -> list[str]:
        return [self.names[i] for i in self.kept]

    def describe(self) -> list[str]:
        """One line per dropped component: what it is merged into (empty: it has no effect)."""
        lines = []
        for name, terms in self.merged.items():
            if not terms:
                lines.append(f"{name}: moves neither collar nor direction; fixed at 0")
            else:
                lines.append(f"{name}: merged into " + " + ".join(f"{c:+.3g} {k}" for k, c in terms))
        return lines


@dataclass
class Identification:
    """Identified twists ``(n_rows, 6)`` (rad, m) and how well they explain the measurements."""

    twists: torch.Tensor
    basis: Basis
    rank: int
    condition: float  # at the measurement joint vectors
    collar_rms_mm: float
    direction_rms_deg: float
    iterations: int
    n_measurements: int
    history: list[float] = field(default_factory=list)  # weighted cost per accepted step


def _priority(boom: Boom) -> list[int]:
    """Parameter indices in the preference order of the module docstring."""
    kind = {j.row: j.param for j in boom.joints}
    classes = []
    for r in range(boom.n_rows):
        for c, comp in enumerate(COMPONENTS):
            variable = (kind.get(r) == "theta" and comp == "rz") or (kind.get(r) == "d" and comp == "tz")
            rank = 0 if variable else 1 if comp in ("rx", "ry") else 2 if comp in ("tx", "ty") else 3
            classes.append((rank, r, c, r * len(COMPONENTS) + c))
    return [i for *_, i in sorted(classes)]


def predict(links: torch.Tensor, frames_p: torch.Tensor, twists: torch.Tensor, tool: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """Collar ``(N, 3)`` and direction ``(N, 3)`` from nominal row transforms ``links (N, rows, 4, 4)``
    and twists ``(rows, 6)``: the same chain as :class:`BoomWithErrors`, differentiable in the twists."""
    E = twist_transforms(frames_p, twists)
    T = E[0] @ links[:, 0]
    for i in range(1, links.shape[1]):  # loop over the rows, batched over measurements
        T = T @ (E[i] @ links[:, i])
    return T[:, :3, :3] @ tool + T[:, :3, 3], T[:, :3, 2]


class _Problem:
    """The weighted residual of measurements as a function of the kept twist components."""

    def __init__(self, boom: Boom, meas: Measurements, weights: Weights, kept: list[int]):
        self.links = boom.link_transforms(meas.q.to(DTYPE))
        self.frames_p = axis_frames(boom)
        self.tool = torch.tensor(boom.tool, dtype=DTYPE)
        self.meas = meas
        self.shape = (boom.n_rows, len(COMPONENTS))
        self.select = torch.eye(boom.n_rows * len(COMPONENTS), dtype=DTYPE)[:, kept]  # kept -> all components
        self.w_pos = 1e-3 * weights.position_mm
        self.w_dir = math.radians(weights.direction_deg)

    def twists(self, x: torch.Tensor) -> torch.Tensor:
        return (self.select @ x).reshape(self.shape)

    def residual(self, x: torch.Tensor) -> torch.Tensor:
        p, z = predict(self.links, self.frames_p, self.twists(x), self.tool)
        r = torch.cat([(p - self.meas.collar) / self.w_pos, (z - self.meas.direction) / self.w_dir], -1)
        return r.reshape(-1)

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        return jacfwd(self.residual)(x)


def _normalised(J: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    norms = J.norm(dim=0)
    return J / torch.where(norms > 0, norms, torch.ones_like(norms)), norms


def identifiable_basis(boom: Boom, weights: Weights = Weights(), n_poses: int = 200, seed: int = 0,
                       tol: float = 1e-6) -> Basis:
    """The identifiable twist components of ``boom`` for collar + direction measurements.

    The Jacobian is taken at ``n_poses`` joint vectors uniform over the ranges (generic poses, so
    what is lost is structural), columns normalised; a component is kept when its column has a
    part of relative size above ``tol`` outside the span of the components kept before it.
    """
    check_supported(boom)
    names = parameter_names(boom)
    g = torch.Generator().manual_seed(int(seed))
    lo, hi = boom.limits(DTYPE)
    q = lo + torch.rand(n_poses, boom.n_joints, generator=g, dtype=DTYPE) * (hi - lo)
    with torch.no_grad():
        p, z = boom.tool_pose(q)
    probe = Measurements(q, p, z, "generic poses")
    everything = list(range(len(names)))
    problem = _Problem(boom, probe, weights, everything)
    J = problem.jacobian(torch.zeros(len(names), dtype=DTYPE))
    Jn, norms = _normalised(J)
    kept: list[int] = []
    Q = torch.zeros(J.shape[0], 0, dtype=DTYPE)
    for i in _priority(boom):
        if norms[i] == 0:
            continue
        r = Jn[:, i] - Q @ (Q.T @ Jn[:, i])
        r = r - Q @ (Q.T @ r)  # second Gram-Schmidt pass against rounding
        if r.norm() > tol:
            kept.append(i)
            Q = torch.cat([Q, (r / r.norm()).unsqueeze(-1)], -1)
    kept.sort()
    merged = {}
    for i in everything:
        if i in kept:
            continue
        if norms[i] == 0:
            merged[names[i]] = []
            continue
        coef = torch.linalg.lstsq(J[:, kept], J[:, i : i + 1]).solution.squeeze(-1)
        share = (coef.abs() * norms[kept]) / norms[i]  # how much of the dropped column each term carries
        terms = [(names[kept[k]], float(coef[k])) for k in share.argsort(descending=True).tolist() if share[k] > 0.05]
        merged[names[i]] = terms
    s = torch.linalg.svdvals(Jn[:, kept])
    return Basis(names, kept, merged, float(s[0] / s[-1]))


def check_measurements(meas: Measurements, boom: Boom) -> None:
    """Shapes and finiteness of measurements, with the row of the first bad value."""
    n = len(meas)
    if meas.q.shape != (n, boom.n_joints) or meas.collar.shape != (n, 3) or meas.direction.shape != (n, 3):
        raise InputError(
            f"{meas.source}: expected q ({n}, {boom.n_joints}), collar ({n}, 3), direction ({n}, 3); got "
            f"{tuple(meas.q.shape)}, {tuple(meas.collar.shape)}, {tuple(meas.direction.shape)}"
        )
    for label, t in (("joints", meas.q), ("collar", meas.collar), ("direction", meas.direction)):
        bad = ~torch.isfinite(t).all(-1)
        if bad.any():
            raise InputError(f"{meas.source}: non-finite {label} in measurement row {int(bad.nonzero()[0]) + 1}")
    norm = meas.direction.norm(dim=-1)
    if ((norm - 1).abs() > 1e-6).any():
        r = int(((norm - 1).abs() > 1e-6).nonzero()[0])
        raise InputError(f"{meas.source}: direction of measurement row {r + 1} has length {float(norm[r]):.6g}, "
                         "expected a unit vector")


def identify(boom: Boom, meas: Measurements, basis: Basis, weights: Weights = Weights(), max_iters: int = 50,
             rank_rtol: float = 1e-9, max_condition: float = 1e8) -> Identification:
    """Fit the ``basis`` components of the error twists of the nominal ``boom`` to ``meas``.

    Raises :class:`InputError` when the measurements cannot identify the basis: fewer equations
    than parameters, a Jacobian of lower rank than the basis (degenerate poses: too few distinct
    joint vectors, or joints that never move), a condition number above ``max_condition``, or
    non-finite data; the message names the parameters that cannot be separated.
    """
    check_measurements(meas, boom)
    n, k = len(meas), len(basis.kept)
    if n * EQUATIONS_PER_MEASUREMENT < k:
        raise InputError(
            f"{meas.source}: {n} measurement(s) give {n * EQUATIONS_PER_MEASUREMENT} equations (collar 3 + "
            f"direction 2 each) for {k} identifiable parameters; need at least "
            f"{math.ceil(k / EQUATIONS_PER_MEASUREMENT)} measurements at distinct poses"
        )
    problem = _Problem(boom, meas, weights, basis.kept)
    x = torch.zeros(k, dtype=DTYPE)
    r, J = problem.residual(x), problem.jacobian(x)
    Jn, _ = _normalised(J)
    U, s, Vh = torch.linalg.svd(Jn, full_matrices=False)
    rank = int((s > rank_rtol * s[0]).sum())
    condition = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    if rank < k or condition > max_condition:
        weak = Vh[-1].abs()
        names = [basis.kept_names[i] for i in weak.argsort(descending=True).tolist() if weak[i] > 0.2]
        joints = sorted({nm.split(".")[0] for nm in names})
        problem_text = f"rank {rank} of {k}" if rank < k else f"condition number {condition:.3g} > {max_condition:.3g}"
        raise InputError(
            f"{meas.source}: the {n} measurement poses cannot separate the error parameters ({problem_text}); "
            f"the weakest combination involves {names}. Measure more poses that move joints {joints} "
            "(distinct joint vectors, each joint over its range)"
        )
    # one problem (a batch of one row); Marquardt scaling treats rad and m alike; the Jacobian is
    # recomputed only at accepted points; stop once a step gains (almost) nothing
    out = least_squares(lambda x, rows, current: Evaluation(problem.residual(x[0])[None]), x[None],
                        jac=lambda x, rows: problem.jacobian(x[0])[None], initial=Evaluation(r[None], J[None]),
                        damping=Damping(initial=1e-3, floor=0.0, down=0.1, lam_max=math.inf, give_up=1e12),
                        max_trials=max_iters, ftol=1e-12, xtol=1e-15, record=True)
    x, iterations = out.x[0], int(out.trials[0])
    history = [float(r @ r)] + [float(c[0]) for c, a in zip(out.costs, out.accepted, strict=True) if a[0]]
    if not torch.isfinite(x).all():
        raise Diverged(f"{meas.source}: identification diverged (non-finite parameters)")
    twists = problem.twists(x)
    p, z = predict(problem.links, problem.frames_p, twists, problem.tool)
    collar = (p - meas.collar).norm(dim=-1)
    angle = torch.atan2(torch.linalg.cross(z, meas.direction, dim=-1).norm(dim=-1), (z * meas.direction).sum(-1))
    return Identification(
        twists=twists.detach(), basis=basis, rank=rank, condition=condition,
        collar_rms_mm=float(collar.pow(2).mean().sqrt() * 1e3),
        direction_rms_deg=math.degrees(float(angle.pow(2).mean().sqrt())),
        iterations=iterations, n_measurements=n, history=history,
    )
