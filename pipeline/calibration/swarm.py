"""The swarms calibration uses for PSO-BP and SSA-BP initial weights: the project's one swarm
(:mod:`pipeline.optim.swarm`), re-exported under the names the calibration study imports."""

from __future__ import annotations

from pipeline.optim.swarm import PSOParams, SSAParams, SwarmResult, pso_minimize, rastrigin, sphere, ssa_minimize

__all__ = ["PSOParams", "SSAParams", "SwarmResult", "pso_minimize", "rastrigin", "sphere", "ssa_minimize"]
