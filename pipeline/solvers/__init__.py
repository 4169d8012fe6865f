"""IK solvers behind one interface (:class:`Solver`): trained networks, the numerical method
of paper 000, the RBF network of paper 001, the PSO family of paper 002 and the GA of paper 003."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pipeline.core.errors import ConfigError
from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import FrameTargets, HoleTargets, NetworkSolver, Solver, SolveResult
from pipeline.solvers.ga import GAParams, GeneticIK
from pipeline.solvers.nm import NMSolver
from pipeline.solvers.pso import ParticleSwarm, params_for
from pipeline.solvers.rbf import RBFSolver

__all__ = ["FrameTargets", "HoleTargets", "Solver", "SolveResult", "build_solver"]

SOLVER_KINDS = ("network", "nm", "rbf", "pso", "ga")


def build_solver(name: str, spec: Mapping, boom: Boom, models_dir: Path, specs: Mapping | None = None) -> Solver:
    """A solver from its config entry ``spec`` (``kind`` plus that solver's parameters).

    ``kind: network`` loads ``models_dir/<network or name>.pt``; an ``nm`` entry with ``init``
    starts from another entry of ``specs`` (e.g. a network) instead of the home pose."""
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind not in SOLVER_KINDS:
        raise ConfigError(f"benchmark.solvers.{name}.kind = {kind!r}: expected one of {list(SOLVER_KINDS)}")
    try:
        if kind == "network":
            from pipeline.learning.models import check_network_fits, load_checkpoint

            path = Path(models_dir) / f"{spec.pop('network', name)}.pt"
            return NetworkSolver(boom, check_network_fits(load_checkpoint(path)[0], boom, str(path)), name)
        if kind == "nm":
            init = spec.pop("init", None)
            if init is not None:
                if specs is None or init not in specs:
                    raise ConfigError(f"benchmark.solvers.{name}.init = {init!r}: no solver of that name")
                spec["init"] = build_solver(init, specs[init], boom, models_dir, specs)
            return NMSolver(boom, name=name, **spec)
        if kind == "rbf":
            return RBFSolver(boom, name=name, **spec)
        if kind == "pso":
            variant = spec.pop("variant", name)
            locks = spec.pop("locks", None)
            return ParticleSwarm(boom, params_for(variant, spec), locks=locks, name=name)
        locks = spec.pop("locks", None)
        return GeneticIK(boom, GAParams(**spec), locks=locks, name=name)
    except TypeError as exc:  # an unknown or missing key in the solver's entry
        raise ConfigError(f"benchmark.solvers.{name}: {exc}") from None
