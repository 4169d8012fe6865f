"""Paper 004's joint-space compensation: BP, PSO-BP and SSA-BP networks from the nominal
(theoretical) joints theta to the joints q the real boom needs.

Training pairs (paper 004, Fig. 3): joints q are given, the real pose T(q) is measured, and
theta = nominal IK of T(q), here started from q so that theta is the nearby solution branch. A
hole is then solved on the nominal model (theta) and the network turns it into q.

Decisions the paper leaves open (config keys under ``calibration.network``):

* ``target``: ``residual`` (default) lets the network output the correction q - theta, added to
  theta; ``direct`` is the paper's literal theta -> q. A direct 8-8-8 tanh network must reproduce
  the identity to far better than the errors (0.01 deg in 90 deg ranges), which it cannot.
* Inputs and outputs are scaled to [-1, 1] per joint from the training data (MATLAB
  ``mapminmax``, the toolbox the paper's settings come from); the MSE and its goal are in those units.
* ``trainer``: ``lm`` (default) is Levenberg-Marquardt, MATLAB's ``trainlm``, the default BP trainer
  that 100 epochs and a 1e-4 goal suggest; ``gd`` is plain gradient descent with ``lr`` (the
  paper's learning rate 0.1, which ``trainlm`` does not use).
* Initial weights: uniform in ``[-weight_bound, weight_bound]`` (BP), or the best of a PSO / SSA
  swarm over that box with the training MSE as fitness (PSO-BP, SSA-BP); then BP trains.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import torch
from torch.func import jacfwd

from pipeline.core.errors import ConfigError, InputError
from pipeline.core.settings import rule
from pipeline.optim.least_squares import Damping, Evaluation, least_squares
from pipeline.optim.scaling import MinMax
from pipeline.optim.swarm import PSOParams, SSAParams, pso_minimize, ssa_minimize
from pipeline.solvers.base import require

DTYPE = torch.float64
TARGETS = ("residual", "direct")
TRAINERS = ("lm", "gd")
INITS = {"bp": "random", "pso-bp": "pso", "ssa-bp": "ssa"}  # method -> how the BP weights start


@dataclass(frozen=True)
class NetworkParams:
    # paper 004: one hidden layer of 8. Bounds (conf/calibration/default.yaml): at most 4 layers of 128, whose
    # weights the swarms carry per particle and LM's Jacobian per measured equation
    hidden: tuple[int, ...] = field(default=(8,), metadata=rule(ge=1, le=128, min_items=1, max_items=4))
    iterations: int = field(default=100, metadata=rule(ge=0, le=100_000))
    lr: float = 0.1  # gradient descent only
    goal: float = 1e-4  # training MSE at which BP stops
    trainer: str = "gd"  # the paper's gradient descent with lr, as conf/calibration and docs say
    target: str = "residual"
    weight_bound: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "hidden", tuple(int(h) for h in self.hidden))
        require({
            "hidden sizes >= 1": len(self.hidden) >= 1 and all(h >= 1 for h in self.hidden),
            "iterations >= 0": self.iterations >= 0,
            "lr > 0": self.lr > 0,
            "goal >= 0": self.goal >= 0,
            f"trainer in {TRAINERS}": self.trainer in TRAINERS,
            f"target in {TARGETS}": self.target in TARGETS,
            "weight_bound > 0": self.weight_bound > 0,
        }, "calibration.network", self)


class MLP:
    """A tanh MLP with a linear output, evaluated for a whole population of weight vectors at once."""

    def __init__(self, sizes: list[int]):
        self.sizes = list(sizes)
        self.n_weights = sum((a + 1) * b for a, b in zip(self.sizes[:-1], self.sizes[1:], strict=True))

    def forward(self, w: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``w (P, n_weights)``, ``x (N, n_in)`` -> ``(P, N, n_out)``."""
        h = x.expand(w.shape[0], *x.shape)
        at = 0
        for k, (a, b) in enumerate(zip(self.sizes[:-1], self.sizes[1:], strict=True)):
            W = w[:, at:at + a * b].reshape(-1, b, a)
            bias = w[:, at + a * b:at + (a + 1) * b].unsqueeze(1)
            at += (a + 1) * b
            h = h @ W.transpose(1, 2) + bias
            if k < len(self.sizes) - 2:
                h = torch.tanh(h)
        return h


@dataclass
class Compensator:
    """A trained network: ``compensator(theta) -> q`` for joint vectors ``(B, n_joints)``."""

    mlp: MLP
    weights: torch.Tensor
    x_scale: MinMax
    y_scale: MinMax
    target: str
    info: dict = field(default_factory=dict)

    def __call__(self, theta: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            y = self.y_scale.inverse(self.mlp.forward(self.weights[None], self.x_scale(theta.double()))[0])
        return theta + y if self.target == "residual" else y


def _train_lm(mlp: MLP, w: torch.Tensor, X: torch.Tensor, Y: torch.Tensor, iterations: int, goal: float):
    """MATLAB ``trainlm``: (J^T J + mu I) step, mu x0.1 on success, x10 on failure; an epoch is one
    Jacobian, and training ends when no mu up to 1e10 lowers the MSE (a minimum)."""
    y = Y.reshape(-1)

    def errors(v: torch.Tensor) -> torch.Tensor:  # (n_weights,) -> (N * n_out,)
        return mlp.forward(v[None], X)[0].reshape(-1) - y

    out = least_squares(lambda v, rows, current: Evaluation(errors(v[0])[None]), w[None],
                        jac=lambda v, rows: jacfwd(errors)(v[0])[None],
                        damping=Damping(initial=1e-3, marquardt=False, down=0.1, lam_min=0.0, lam_max=math.inf,
                                        give_up=1e10),
                        max_steps=iterations, cost=lambda e: (e * e).mean(-1), cost_tol=goal)
    return out.x[0], float(out.cost[0]), int(out.jacobians[0])


def _train_gd(mlp: MLP, w: torch.Tensor, X: torch.Tensor, Y: torch.Tensor, iterations: int, goal: float,
              lr: float):
    """MATLAB ``traingd``: full-batch gradient descent on the MSE with a fixed learning rate."""
    done = 0
    for done in range(1, iterations + 1):
        w = w.detach().requires_grad_(True)
        mse = ((mlp.forward(w[None], X)[0] - Y) ** 2).mean()
        if float(mse.detach()) <= goal:
            done -= 1
            break
        (grad,) = torch.autograd.grad(mse, w)
        w = w - lr * grad
    w = w.detach()
    return w, float(((mlp.forward(w[None], X)[0] - Y) ** 2).mean()), done


def fit_compensator(theta: torch.Tensor, q: torch.Tensor, params: NetworkParams, method: str, seed: int,
                    pso: PSOParams | None = None, ssa: SSAParams | None = None) -> Compensator:
    """Train ``method`` (``bp``, ``pso-bp`` or ``ssa-bp``) on pairs ``theta -> q`` ``(N, n_joints)``."""
    if method not in INITS:
        raise ConfigError(f"compensation method {method!r}: expected one of {sorted(INITS)}")
    if theta.shape != q.shape or theta.ndim != 2 or len(theta) < 2:
        raise InputError(f"compensation training pairs: need theta and q of the same shape (N >= 2, n_joints), got "
                         f"{tuple(theta.shape)} and {tuple(q.shape)}")
    if not (torch.isfinite(theta).all() and torch.isfinite(q).all()):
        raise InputError("compensation training pairs: non-finite joints")
    start = time.perf_counter()
    theta, q = theta.double(), q.double()
    target = q - theta if params.target == "residual" else q
    x_scale, y_scale = MinMax.fit(theta), MinMax.fit(target)
    X, Y = x_scale(theta), y_scale(target)
    n = theta.shape[1]
    mlp = MLP([n, *params.hidden, n])
    b = params.weight_bound

    def mse(w: torch.Tensor) -> torch.Tensor:  # training MSE of a population of weight vectors: the swarm's fitness
        return ((mlp.forward(w, X) - Y) ** 2).mean((-1, -2))

    init = INITS[method]
    if init == "random":
        g = torch.Generator().manual_seed(int(seed))
        w = (2 * torch.rand(mlp.n_weights, generator=g, dtype=DTYPE) - 1) * b
    elif init == "pso":
        w = pso_minimize(mse, -b, b, mlp.n_weights, pso or PSOParams(), seed).x
    else:
        w = ssa_minimize(mse, -b, b, mlp.n_weights, ssa or SSAParams(), seed).x
    mse_init = float(mse(w[None])[0])
    if params.trainer == "lm":
        w, mse_final, iters = _train_lm(mlp, w, X, Y, params.iterations, params.goal)
    else:
        w, mse_final, iters = _train_gd(mlp, w, X, Y, params.iterations, params.goal, params.lr)
    info = {"mse_init": mse_init, "mse": mse_final, "iterations": iters, "samples": len(theta),
            "fit_s": time.perf_counter() - start}
    return Compensator(mlp, w, x_scale, y_scale, params.target, info)


def training_pairs(nominal, measurements, depth: float | None = None, pair_tol: float = 1e-6, **nm) -> tuple[
        torch.Tensor, torch.Tensor, torch.Tensor]:
    """Paper 004's pairs from measurements: ``theta`` = nominal IK of the measured pose, started
    from the measured joints ``q`` (so theta is the nearby branch). Returns ``theta``, ``q`` and a
    mask of the pairs whose nominal IK reached the measured pose within ``pair_tol`` (m); the others
    (measured poses the nominal model cannot reach near q, e.g. at a joint limit) are no pair."""
    from pipeline.calibration.ik import solve_holes

    depth = nominal.preview_depth if depth is None else depth
    theta, err = solve_holes(nominal, measurements.pose6(depth), start=measurements.q, restarts=0, **nm)
    return theta, measurements.q, err <= pair_tol
