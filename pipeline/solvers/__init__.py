"""IK solvers behind one interface (:class:`Solver`): trained networks, the numerical method
of paper 000, the RBF network of paper 001, the PSO family of paper 002, the GA of paper 003, and
the hybrid solver (a network's answer refined to the exact pose under the safety model)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pipeline.core.errors import ConfigError
from pipeline.core.settings import SEED_MAX, check_rule, coerce, parse, unknown_keys
from pipeline.geometry.collision import SafetyModel
from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import FrameTargets, HoleTargets, NetworkSolver, Solver, SolveResult
from pipeline.solvers.ga import GAParams, GeneticIK
from pipeline.solvers.hybrid import HybridSettings, HybridSolver
from pipeline.solvers.nm import NMSolver
from pipeline.solvers.pso import ParticleSwarm, params_for
from pipeline.solvers.rbf import RBFSolver

__all__ = ["FrameTargets", "HoleTargets", "Solver", "SolveResult", "build_solver"]

SOLVER_KINDS = ("network", "nm", "rbf", "pso", "ga", "hybrid", "hybrid_compiled", "rtb_ik_lm", "pinocchio_clik")
PEER_KINDS = ("rtb_ik_lm", "pinocchio_clik")  # the optional `peers` extra (pipeline/solvers/peers.py)


def _init_solver(name: str, init, boom: Boom, models_dir: Path, specs: Mapping | None, safety) -> Solver | None:
    if init is None:
        return None
    if specs is None or init not in specs:
        raise ConfigError(f"solver_benchmark.solvers.{name}.init = {init!r}: no solver of that name")
    return build_solver(init, specs[init], boom, models_dir, specs, safety)


HYBRID_ENTRY = ("init",)  # a hybrid entry's own keys: its settings are the `solver` group (conf/solver/hybrid.yaml)
# keys of a benchmark entry that are the harness's (how many holes, how many timed alone), not the solver's
HARNESS_KEYS = ("max_holes", "single")

# Bounds of the sizes of a solver entry (conf/solver_benchmark/default.yaml), checked when the group is parsed:
# beyond them a solver only runs out of time or memory. An exact RBF solves a dense train x train system (20 000:
# 3.2 GB), a swarm or GA evaluates population x holes boom poses a step, the GA's workspace boxes take grid^joints
# forward kinematics (10^6 on rescue6), and NM's restarts and the peers' limits are iterations of every hole.
HARNESS_BOUNDS = {"max_holes": (1, 1_000_000), "single": (0, 10_000)}  # every entry's HARNESS_KEYS
ENTRY_BOUNDS: dict[str, dict[str, tuple[int, int]]] = {  # by kind
    "nm": {"max_iters": (1, 10_000), "restarts": (0, 1000), "seed": (0, SEED_MAX)},
    "rbf": {"samples": (2, 20_000), "train": (1, 20_000), "roll_grid": (0, 360), "seed": (0, SEED_MAX)},
    "pso": {"population": (2, 10_000), "iterations": (1, 10_000), "seed": (0, SEED_MAX)},
    "ga": {"population": (4, 10_000), "generations": (1, 10_000), "grid": (2, 10), "seed": (0, SEED_MAX)},
    "rtb_ik_lm": {"ilimit": (1, 10_000), "slimit": (1, 10_000), "restarts": (0, 1000), "seed": (0, SEED_MAX)},
    "pinocchio_clik": {"max_iters": (1, 10_000), "restarts": (0, 1000), "seed": (0, SEED_MAX)},
}


def check_entry(name: str, spec: Mapping, where: str = "solver_benchmark.solvers") -> None:
    """ConfigError naming the first size of the entry ``spec`` out of its range (:data:`ENTRY_BOUNDS`), before any
    solver is built; its other keys are checked when it is built."""
    if not isinstance(spec, Mapping):
        raise ConfigError(f"{where}.{name} = {spec!r}: expected a mapping with kind and that solver's parameters")
    kind = spec.get("kind")
    bounds = {**HARNESS_BOUNDS, **(ENTRY_BOUNDS.get(kind, {}) if isinstance(kind, str) else {})}
    for key, (lo, hi) in bounds.items():
        if spec.get(key) is not None:
            value = coerce(spec[key], "int", f"{where}.{name}.{key}")
            check_rule(value, f"{where}.{name}.{key}", ge=lo, le=hi)


def build_solver(name: str, spec: Mapping, boom: Boom, models_dir: Path, specs: Mapping | None = None,
                 safety: SafetyModel | None = None, start_box=None, hybrid: HybridSettings | None = None) -> Solver:
    """A solver from its config entry ``spec`` (``kind`` plus that solver's parameters).

    ``kind: network`` loads ``models_dir/<network or name>.pt``; an ``nm`` or ``hybrid`` entry with
    ``init`` starts from another entry of ``specs`` (e.g. a network) instead of the home pose; a
    ``hybrid`` entry runs with ``hybrid`` (the parsed ``solver`` group; its defaults when None), needs
    the ``safety`` model it keeps, and draws its random starts within ``start_box`` (lower, upper
    joints; the working box) when given."""
    spec = {k: v for k, v in spec.items() if k not in HARNESS_KEYS}
    kind = spec.pop("kind", None)
    if kind not in SOLVER_KINDS:
        raise ConfigError(f"solver_benchmark.solvers.{name}.kind = {kind!r}: expected one of {list(SOLVER_KINDS)}")
    try:
        if kind in ("hybrid", "hybrid_compiled"):
            if safety is None:
                raise ConfigError(f"solver_benchmark.solvers.{name}: the hybrid solver needs the safety model")
            unknown_keys(spec, HYBRID_ENTRY, f"solver_benchmark.solvers.{name}",
                         "; the hybrid's settings are the solver group (solver.*, conf/solver/hybrid.yaml)")
            init = _init_solver(name, spec.pop("init", None), boom, models_dir, specs, safety)
            settings = hybrid or parse(HybridSettings, {}, "solver")
            if kind == "hybrid_compiled":  # the same solver, its fast path and refinements compiled (numba)
                from pipeline.solvers.compiled import CompiledHybridSolver

                return CompiledHybridSolver(boom, safety, init, settings, name, start_box)
            return HybridSolver(boom, safety, init, settings, name, start_box)
        if kind in PEER_KINDS:  # raises PeersUnavailable (an ImportError) with the install line
            from pipeline.solvers.peers import build_peer

            return build_peer(kind, boom, **spec)
        if kind == "network":
            from pipeline.learning.network_source import load_network

            unknown_keys(spec, ("network",), f"solver_benchmark.solvers.{name}")
            path = Path(models_dir) / f"{spec.pop('network', name)}.pt"
            return NetworkSolver(boom, load_network(path, boom)[0], name)
        if kind == "nm":
            spec["init"] = _init_solver(name, spec.pop("init", None), boom, models_dir, specs, safety)
            return NMSolver(boom, name=name, **spec)
        if kind == "rbf":  # samples from the working box unless the entry says in_box: false
            box = start_box if spec.pop("in_box", True) else None
            return RBFSolver(boom, name=name, box=box, **spec)
        if kind == "pso":
            variant = spec.pop("variant", name)
            locks = spec.pop("locks", None)
            return ParticleSwarm(boom, params_for(variant, spec), locks=locks, name=name)
        locks = spec.pop("locks", None)
        return GeneticIK(boom, GAParams(**spec), locks=locks, name=name)
    except TypeError as exc:  # an unknown or missing key in the solver's entry
        raise ConfigError(f"solver_benchmark.solvers.{name}: {exc}") from None
