"""Executing a planned round by events (spec section 8): actions, the conflicts of their sweeps, the
interlocks that make any drilling durations safe, the execution rule, and Monte Carlo draws.

- :mod:`~pipeline.execution.actions`: a timeline as each boom's actions; the actions and interlocks
  files (written and read back with validation);
- :mod:`~pipeline.execution.sweeps`: which pairs of actions of two booms can come within d_boom at
  any relative timing (certified over each action's whole sweep);
- :mod:`~pipeline.execution.graph`: the dependency graph (topological order, cycles, reduction);
- :mod:`~pipeline.execution.interlocks`: the robust construction (order every conflicting pair);
- :mod:`~pipeline.execution.executor`: the execution rule over a batch of drilling-time draws;
- :mod:`~pipeline.execution.montecarlo`: the draws and their summary;
- :mod:`~pipeline.execution.robust`: the schedule stage's hook (interlocks, draws, one realised round);
- :mod:`~pipeline.execution.trajectory`: an executed round's trajectory from the planned file's rows;
- :mod:`~pipeline.execution.executed`: an executed round's round table, summary pieces, draws file;
- :mod:`~pipeline.execution.interrupt`: a hole that cannot be finished, and the round handed on.
"""
