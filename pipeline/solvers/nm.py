"""Paper 000's numerical method ("NM"), implemented as Levenberg-Marquardt on the pose residual.

Batched over targets: every target keeps its own damping and stops on its own. Joint limits
hold by projection (each step is clamped into the ranges). Two variants:

* redundant (default): all free joints, the damped step ``(J^T J + lambda I)^-1 J^T r`` picks
  among the many solutions of 6 equations in 8 unknowns;
* ``couplings``: linear equations between joints appended to the residual, as paper 000 adds
  two to remove the redundancy (its theta2 - theta4 = -180 deg and theta5 + theta1 = -90 deg are
  written in its own joint zeros; ``solvers.nm_coupled`` in ``conf/solver_benchmark/default.yaml`` gives
  their jumbo8 equivalent).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch

from pipeline.core.errors import ConfigError
from pipeline.geometry.kinematics import Boom
from pipeline.optim.least_squares import Damping, Evaluation, least_squares
from pipeline.solvers.base import JointSpace, Solver, Targets, tool_transform


class Couplings:
    """Linear joint equations ``sum_k c_k q_k = value`` (SI units), one row each."""

    def __init__(self, space: JointSpace, rows: Sequence[Mapping]):
        self.A = torch.zeros(len(rows), space.n, dtype=torch.float64)
        self.b = torch.zeros(len(rows), dtype=torch.float64)
        for r, row in enumerate(rows):
            coeffs, value = row.get("coeffs"), row.get("value", 0.0)
            if not isinstance(coeffs, Mapping) or not coeffs:
                raise ConfigError(f"couplings[{r}].coeffs: expected a mapping joint -> coefficient, got {coeffs!r}")
            for name, c in coeffs.items():
                if name not in space.names:
                    raise ConfigError(f"couplings[{r}].coeffs: '{name}' is not a free joint of {space.names}")
                self.A[r, space.names.index(name)] = float(c)
            self.b[r] = float(value)

    def __len__(self) -> int:
        return self.A.shape[0]

    def residual(self, x: torch.Tensor) -> torch.Tensor:
        return x @ self.A.T.to(x) - self.b.to(x)


class NMSolver(Solver):
    """NM: damped Newton (Levenberg-Marquardt) on ``r(q) = [pose residual, couplings]`` with projected joint limits."""

    name = "nm"

    def __init__(
        self,
        boom: Boom,
        max_iters: int = 100,
        tol: float = 1e-7,
        damping: float = 1e-3,
        restarts: int = 0,
        couplings: Sequence[Mapping] = (),
        locks: Mapping[str, float] | None = None,
        seed: int = 0,
        name: str = "nm",
        init: Solver | None = None,
    ):
        super().__init__(boom)
        if max_iters < 1 or tol <= 0 or damping <= 0 or restarts < 0:
            raise ConfigError(
                f"{name}: max_iters >= 1, tol > 0, damping > 0 and restarts >= 0 are required "
                f"(got {max_iters}, {tol}, {damping}, {restarts})"
            )
        self.space = JointSpace(boom, locks)
        self.couplings = Couplings(self.space, couplings)
        self.max_iters, self.tol, self.damping, self.restarts, self.seed = max_iters, tol, damping, restarts, seed
        self.name = name
        self.init = init  # a solver whose answer is the starting point (e.g. CUIKM: safe and close)

    def residual(self, x: torch.Tensor, targets: Targets) -> torch.Tensor:
        r = targets.residual(tool_transform(self.boom, self.space.full(x)))
        return torch.cat([r, self.couplings.residual(x)], dim=-1) if len(self.couplings) else r

    def jacobian(self, x: torch.Tensor, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        """Residual ``(B, m)`` and its Jacobian ``(B, m, n)``: one reverse pass per equation
        (rows are independent across the batch, so the gradient of a column sum is per row)."""
        with torch.enable_grad():
            x = x.detach().requires_grad_(True)
            r = self.residual(x, targets)
            m = r.shape[1]
            rows = [torch.autograd.grad(r[:, k].sum(), x, retain_graph=k < m - 1)[0] for k in range(m)]
        return r.detach(), torch.stack(rows, dim=1)

    def _descend(self, x: torch.Tensor, targets: Targets) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Run LM from ``x``; returns the final point, its cost ``|r|^2`` and iterations used."""
        def fun(x: torch.Tensor, rows: torch.Tensor, current: Evaluation | None) -> Evaluation:
            return Evaluation(*self.jacobian(x, targets.subset(rows)))

        # Marquardt scaling (the default) keeps prismatic (m) and revolute (rad) joints on comparable footing
        out = least_squares(fun, x, damping=Damping(initial=self.damping), max_trials=self.max_iters,
                            cost_tol=self.tol**2, project=self.space.clamp)
        return out.x, out.cost, out.trials

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        B = len(targets)
        if self.init is not None:
            x0 = self.space.clamp(self.init.joints(targets)[:, self.space.free])
        else:  # start mid-range, a fixed home pose
            x0 = (0.5 * (self.space.lower + self.space.upper)).expand(B, -1).clone()
        x, cost, iters = self._descend(x0, targets)
        g = torch.Generator().manual_seed(self.seed)
        for _ in range(self.restarts):  # random restarts only for the targets not yet solved
            todo = (cost > self.tol**2).nonzero().flatten()
            if len(todo) == 0:
                break
            xr, cr, ir = self._descend(self.space.uniform((len(todo),), g), targets.subset(todo))
            better = cr < cost[todo]
            x[todo[better]], cost[todo[better]] = xr[better], cr[better]
            iters[todo] += ir
        return self.space.full(x), iters
