"""Numerical optimisers with no knowledge of booms: the one damped least-squares solver
(:mod:`.least_squares`), the one swarm (:mod:`.swarm`) and the one min-max scaler (:mod:`.scaling`).
Imports only :mod:`pipeline.core`."""
